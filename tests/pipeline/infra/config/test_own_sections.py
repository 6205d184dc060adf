"""Config sections that extensions declare (pipeline/infra/config/own.py): a model provider's
``[models.<key>]`` / ``[evaluate.<key>]`` and a dataset source's ``[data.<name>]`` are loaded,
range-checked and refused with the key named like every section, enter the section hashes the
stage keys use and the recorded config, and a provider's cost term joins the evaluate estimate."""
from __future__ import annotations

import dataclasses

import pytest

from pipeline.infra.config import ConfigError, Config, ModelsConfig, load_config, to_dict
from pipeline.infra.config.fields import setting
from pipeline.infra.config.own import with_own
from tests.conftest import ROOT
from tests.support.outside_package import run_with

SMOKE = ROOT / "configs" / "smoke.toml"


def _error(tmp_path, text: str) -> str:
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    return str(e.value)[len(str(path)) + 2:]


# The messages the loader gave when these sections were fields of [models] and [evaluate].
@pytest.mark.parametrize("text, message", [
    ("[models.dirichlet]\nbogus = 1", "unknown key 'models.dirichlet.bogus' (allowed here: accelerate, entries, "
                                      "floor, max_iter, passes, tol)"),
    ("[models.dirichlet]\nfloor = 1.0", "'models.dirichlet.floor' = 1.0 is above the maximum 0.01"),
    ("[models.dirichlet]\npasses = 'x'", "'models.dirichlet.passes' = 'x' is not one of 'deterministic', 'dropout', "
                                         "'both'"),
    ("[models]\ndirichlet = 3", "'models.dirichlet' must be a table"),
    ("[models.dirichlet]\nentries = 9", "'models.dirichlet.entries' = 9 exceeds 'models.n_components' = 4: it keeps "
                                        "that many of the chosen components"),
    ("[features]\nbigbird_samples = 0\n[models]\ntargets = 'deterministic'\n[models.dirichlet]\npasses = 'dropout'",
     "'models.dirichlet.passes' = 'dropout' needs MC-dropout passes of the BigBIRD views ('features.bigbird_samples' "
     "> 0)"),
    ("[evaluate.dirichlet]\nn_ss = 0", "'evaluate.dirichlet.n_ss' = 0 is below the minimum 1"),
    ("[evaluate.dirichlet]\nn_ss = 'a'", "'evaluate.dirichlet.n_ss' must be an integer, got 'a'"),
    ("[evaluate.dirichlet]\nbogus = 1", "unknown key 'evaluate.dirichlet.bogus' (allowed here: n_ss)"),
])
def test_a_providers_keys_are_refused_naming_the_key_as_before(tmp_path, text, message):
    assert _error(tmp_path, text) == message


def test_the_unknown_key_message_lists_the_providers_section_among_the_keys(tmp_path):
    assert "dirichlet, hyperprior" in _error(tmp_path, "[models]\nbogus = 1")


def test_a_loaded_config_equals_a_hand_made_one_and_reads_the_providers_settings():
    cfg = load_config(SMOKE)
    made = dataclasses.replace(Config(), **{f.name: getattr(cfg, f.name) for f in dataclasses.fields(Config)
                                            if f.name not in ("models", "evaluate")},
                               models=dataclasses.replace(cfg.models, own=ModelsConfig().own),
                               evaluate=cfg.evaluate)
    assert cfg.models.dirichlet.passes == "deterministic" and cfg.evaluate.dirichlet.n_ss == 20
    assert made == cfg and hash(made) == hash(cfg)       # the unbuilt section reads as its defaults
    other = dataclasses.replace(cfg, models=with_own(cfg.models, dirichlet=type(cfg.models.dirichlet)(floor=1e-5)))
    assert other != cfg and other.models.dirichlet.floor == 1e-5
    assert to_dict(cfg)["models"]["dirichlet"]["floor"] == 1e-6 and to_dict(cfg)["evaluate"]["dirichlet"] == {"n_ss": 20}
    assert cfg.section("evaluate.dirichlet.n_ss") == 20


def test_the_providers_keys_change_the_models_and_evaluate_keys(tmp_config):
    from stages.framework.registry import STAGES
    from stages.framework.runner import stage_key

    base = tmp_config()

    def keys(cfg):
        return {s: stage_key(cfg, STAGES[s], {u: "x" for u in STAGES[s].upstream})[0] for s in ("models", "evaluate")}

    k0 = keys(base)
    k1 = keys(tmp_config({"evaluate": {"dirichlet": {"n_ss": 7}}}))
    assert k1["evaluate"] != k0["evaluate"] and k1["models"] == k0["models"]
    k2 = keys(tmp_config({"models": {"dirichlet": {"max_iter": 7}}}))
    assert k2["models"] != k0["models"]


OUTSIDE = '''
import dataclasses
import viewfuse as vf        # the provider's side: the public names only (docs/extending.md)
from pipeline.infra.config import ConfigError, load_config, to_dict
from pipeline.infra.cost import evaluate_terms

@dataclasses.dataclass(frozen=True)
class Fit:
    width: int = vf.setting(3, lo=1, hi=9, doc="how wide")

@dataclasses.dataclass(frozen=True)
class Use:
    draws: int = vf.setting(5, lo=1, hi=100)

@vf.register_provider
class Mine(vf.ModelProvider):
    key = "mine_test"
    sections = {"models.mine_test": Fit, "evaluate.mine_test": Use}
    def check(self, cfg, need):
        need(cfg.models.mine_test.width <= cfg.models.n_components, "'models.mine_test.width' exceeds n_components")
    def cost(self, cfg, rows):
        return [vf.Term("mine", ("evaluate.mine_test.draws",), seconds=rows * cfg.evaluate.mine_test.draws)]

smoke = SMOKE_PATH
cfg = load_config(smoke)
print("defaults", cfg.models.mine_test.width, cfg.evaluate.mine_test.draws, to_dict(cfg)["models"]["mine_test"])
set2 = load_config(smoke, {"models": {"mine_test": {"width": 2}}})
print("hash", set2.section_hash("models") != cfg.section_hash("models"), cfg.section_hash("evaluate") ==
      set2.section_hash("evaluate"))
for bad in ({"models": {"mine_test": {"width": 10}}}, {"models": {"mine_test": {"width": 5}}},
            {"evaluate": {"mine_test": {"nope": 1}}}):
    try:
        load_config(smoke, bad)
    except ConfigError as e:
        print("refused", str(e).split(": ", 1)[1])
terms = [t for t in evaluate_terms(cfg) if t.what == "mine"]
print("cost", len(terms), terms[0].seconds > 0)
vf.unregister_provider("mine_test")
cfg = load_config(smoke)
print("gone", "mine_test" in to_dict(cfg)["models"], [t.what for t in evaluate_terms(cfg) if t.what == "mine"])
@vf.register_provider
class Clash(vf.ModelProvider):
    key = "clash_test"
    sections = {"models.seed": Fit}
try:
    load_config(smoke)
except ConfigError as e:
    print("clash", str(e).split(": ", 1)[1])
'''


def test_an_outside_providers_sections_load_check_hash_and_cost(tmp_path):
    r = run_with(None, OUTSIDE.replace("SMOKE_PATH", repr(str(SMOKE))), tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    assert lines[0] == "defaults 3 5 {'width': 3}"
    assert lines[1] == "hash True True"
    assert lines[2:5] == ["refused 'models.mine_test.width' = 10 is above the maximum 9",
                          "refused 'models.mine_test.width' exceeds n_components",
                          "refused unknown key 'evaluate.mine_test.nope' (allowed here: draws)"]
    assert lines[5] == "cost 1 True"
    assert lines[6] == "gone False []"
    assert lines[7] == "clash an extension declares the section 'models.seed', already a key of [models]"


@pytest.mark.parametrize("first", ["pipeline.method.methods.dirichlet", "pipeline.method.provider",
                                   "pipeline.infra.config.own"])
def test_any_first_import_sees_the_providers_sections(tmp_path, first):
    r = run_with(None, f"import {first}\nfrom pipeline.infra.config import load_config\n"
                       f"print(load_config({str(SMOKE)!r}).evaluate.dirichlet.n_ss)", tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "20"


def test_a_dataset_sources_section_is_in_the_recorded_config_and_the_data_hash(tmp_config):
    from pipeline.infra.datasets import DatasetSource, register_dataset, unregister_dataset

    @dataclasses.dataclass(frozen=True)
    class Own:
        step: int = setting(10, lo=1, hi=90)

    class WithSection(DatasetSource):
        name = "with_section_test"
        config = Own
        writes = False

    register_dataset(WithSection)
    try:
        cfg = tmp_config({"data": {"source": "with_section_test", "with_section_test": {"step": 20}}})
        assert cfg.data.options == Own(20)
        assert to_dict(cfg)["data"]["with_section_test"] == {"step": 20}     # the run's config.json
        assert to_dict(cfg.section("data"))["with_section_test"] == {"step": 20}   # the data manifest's
        other = tmp_config({"data": {"source": "with_section_test", "with_section_test": {"step": 30}}})
        assert other.section_hash("data") != cfg.section_hash("data")
        assert "with_section_test" not in to_dict(tmp_config())["data"]       # another source: no section
    finally:
        unregister_dataset("with_section_test")


def test_the_providers_cost_term_joins_the_evaluate_estimate_through_the_hook(tmp_config):
    from pipeline.infra.cost import evaluate_terms

    def clouds(n_ss):
        terms = [t for t in evaluate_terms(tmp_config({"evaluate": {"dirichlet": {"n_ss": n_ss}}}))
                 if t.keys == ("evaluate.dirichlet.n_ss",)]
        assert len(terms) == 1
        return terms[0].seconds

    assert clouds(40) == pytest.approx(2 * clouds(20)) and clouds(20) > 0   # linear in N_ss
