import dataclasses

import pytest

from pipeline.infra.config import ConfigError, load_config, parse_override, to_dict
from pipeline.infra.config.load import merge
from tests.conftest import DEFAULT_CONFIG, ROOT


def write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_default_config_loads_and_matches_dataclass_defaults():
    cfg = load_config(DEFAULT_CONFIG)
    assert cfg.run.name == "synthetic"
    assert cfg.evaluate.targets == "all" and cfg.models.classes == "all"
    assert cfg.root == ROOT
    assert cfg.run_dir == ROOT / "artifacts" / "synthetic"
    # The file spells out the defaults: an empty config gives the same sections.
    assert to_dict(cfg) == to_dict(dataclasses.replace(cfg))


def test_unknown_key_names_key_and_file(tmp_path):
    p = write(tmp_path, "[features]\nmargn = 0.1\n")
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert "features.margn" in str(e.value) and str(p) in str(e.value)


def test_unknown_nested_key(tmp_path):
    p = write(tmp_path, "[evaluate.randomized]\nrealisations = 5\n")
    with pytest.raises(ConfigError, match="evaluate.randomized.realisations"):
        load_config(p)


@pytest.mark.parametrize("text, key", [
    ("[features]\nn_samples = 0\n", "features.n_samples"),
    ("[classifier]\ndropout = 1.5\n", "classifier.dropout"),
    ("[run]\ndevice = 'tpu'\n", "run.device"),
    ("[features]\nmax_difficulty = 'easy'\n", "features.max_difficulty"),
    ("[data.synthetic]\nangle_step_deg = 4\n", "data.synthetic.angle_step_deg"),
    ("[evaluate]\ntarget = 'red_cup'\n", "evaluate.target"),
    ("[evaluate]\ntargets = 'every'\n", "evaluate.targets"),
    ("[models]\nclasses = ['pepto_bismol', 'mahatma_rice']\n[evaluate]\ntargets = ['red_cup']\n", "evaluate.targets"),
    ("[evaluate]\nablations = ['models.restarts=3']\n", "evaluate.ablations"),
    ("[evaluate]\nrandomized.sigmas_m = [-0.1]\n", "evaluate.randomized.sigmas_m"),
    ("[models]\nlength_scale_bounds = [1.0, 0.5]\n", "models.length_scale_bounds"),
    ("[data.synthetic]\nbigbird_cameras = [6]\n", "data.synthetic.bigbird_cameras"),
])
def test_out_of_range_values_are_errors(tmp_path, text, key):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert key in str(e.value) and str(p) in str(e.value)


def test_bool_is_not_an_int(tmp_path):
    with pytest.raises(ConfigError, match="features.n_samples"):
        load_config(write(tmp_path, "[features]\nn_samples = true\n"))


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[run\n"))


def test_overrides_and_section_hash(tmp_path):
    a = load_config(DEFAULT_CONFIG)
    b = load_config(DEFAULT_CONFIG, parse_override("features.margin=0.3"))
    assert b.features.margin == 0.3
    assert a.section_hash("features") != b.section_hash("features")
    assert a.section_hash("models") == b.section_hash("models")


def test_parse_override_types():
    assert parse_override("a.b=3") == {"a": {"b": 3}}
    assert parse_override("x=[1, 2]") == {"x": [1, 2]}
    assert parse_override("name=hello") == {"name": "hello"}
    with pytest.raises(ConfigError):
        parse_override("novalue")


def test_real_template_is_valid():
    cfg = load_config(ROOT / "configs" / "avd.toml")
    assert cfg.data.source == "real"
    assert cfg.classifier.weights == "imagenet"
    assert cfg.evaluate.targets == ("aunt_jemima_original_syrup",) and cfg.evaluate.yaws_deg == (0.0,)


def test_ablation_config_applies_and_validates_one_models_key(tmp_path):
    from pipeline.infra.config import ablation_config
    cfg = load_config(DEFAULT_CONFIG)
    v = ablation_config(cfg, "models.noise_floor=dropout")
    assert v.models.noise_floor == "dropout" and v.evaluate == cfg.evaluate
    assert ablation_config(cfg, "models.component_rule=top_min").models.component_rule == "top_min"
    with pytest.raises(ConfigError, match="models.component_rule"):
        ablation_config(cfg, "models.component_rule=best")


def test_dotted_section_is_one_key():
    cfg = load_config(DEFAULT_CONFIG)
    assert cfg.section("evaluate.n_candidates") == 4
    assert cfg.section("evaluate.randomized.sigmas_m") == cfg.evaluate.randomized.sigmas_m


def test_extends_inherits_and_overrides(tmp_path):
    base = tmp_path / "base.toml"
    base.write_text('[run]\nname = "b"\n[evaluate.randomized]\nrealizations = 7\nn_loc_samples = 3\n')
    child = tmp_path / "child.toml"
    child.write_text('extends = "base.toml"\n[evaluate.randomized]\nrealizations = 11\n')
    cfg = load_config(child)
    assert (cfg.run.name, cfg.evaluate.randomized.realizations, cfg.evaluate.randomized.n_loc_samples) == ("b", 11, 3)
    (tmp_path / "loop.toml").write_text('extends = "loop.toml"\n')
    with pytest.raises(ConfigError, match="cycle"):
        load_config(tmp_path / "loop.toml")
    (tmp_path / "gone.toml").write_text('extends = "nope.toml"\n')
    with pytest.raises(ConfigError, match="nope.toml"):
        load_config(tmp_path / "gone.toml")


def test_paper_grade_preset_changes_only_the_population():
    pg = load_config(ROOT / "configs" / "paper_grade.toml")
    default = load_config(DEFAULT_CONFIG)
    assert (pg.evaluate.randomized.realizations, pg.evaluate.randomized.n_loc_samples) == (500, 100)
    assert pg.run.name == "paper_grade"
    for section in ("data", "classifier", "features", "models"):   # upstream stages are shared
        assert pg.section_hash(section) == default.section_hash(section)
    # The extra With Uncertainty variants are off (their cost: the preset comments); the rest is the default.
    assert (pg.evaluate.ablations, pg.evaluate.attribution) == ((), False)
    assert dataclasses.replace(pg.evaluate, randomized=default.evaluate.randomized,
                               ablations=default.evaluate.ablations,
                               attribution=default.evaluate.attribution) == default.evaluate
    # and they come back with --set, as the preset says
    back = load_config(ROOT / "configs" / "paper_grade.toml", merge(
        parse_override('evaluate.ablations=["evaluate.test_domain_variance=cross_fit"]'),
        parse_override("evaluate.attribution=true")))
    assert dataclasses.replace(back.evaluate, randomized=default.evaluate.randomized) == default.evaluate
