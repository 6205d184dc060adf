"""The category benchmark with the instance term and its two documented variants (clutter on both
sides, every fold class a candidate) load and pass the config checks, each differing from the base
in the keys it names only (and the instance config's declared primary comparison: the term against
itself without it)."""
from pathlib import Path

import pytest

from pipeline.infra.config import load_config, to_dict

ROOT = Path(__file__).resolve().parents[4]
CONFIG = ROOT / "configs" / "real_category_instance.toml"
BASE = ROOT / "configs" / "real_category.toml"


def _flat(d, prefix=""):
    """Dotted key -> value of a config, the extensions' own keys and sections included (``to_dict``)."""
    out = {}
    for k, v in (to_dict(d) if hasattr(d, "__dataclass_fields__") else d).items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = tuple(v) if isinstance(v, list) else v
    return out


def test_the_instance_config_is_the_category_benchmark_with_the_term():
    cfg, base = load_config(CONFIG), load_config(BASE)
    assert cfg.models.instance_term and not base.models.instance_term
    diff = {k for k, v in _flat(cfg).items() if _flat(base).get(k) != v}
    assert diff == {"models.instance_term", "run.name", "evaluate.primary.methods"}
    assert cfg.models.instance_prior == "split"   # the default, written out there with its reason
    assert cfg.evaluate.primary.methods[0] == "with_uncertainty_instance"


@pytest.mark.parametrize("over,changed", [
    ({"data": {"real_imagery": {"background": "avd_frames"}}}, ("data.real_imagery.background", "avd_frames")),
    ({"evaluate": {"candidates": "all"}}, ("evaluate.candidates", "all")),
])
def test_the_documented_variants_load_and_change_one_key(over, changed):
    cfg, plain = load_config(CONFIG, over), _flat(load_config(CONFIG))
    got = _flat(cfg)
    assert cfg.models.instance_term and cfg.evaluate.candidate_folds
    key, want = changed
    assert got[key] == want or got[key] == (want,)
    assert {k for k, v in got.items() if plain.get(k) != v} == {key}
    assert f"--set {key}={want}" in CONFIG.read_text()
