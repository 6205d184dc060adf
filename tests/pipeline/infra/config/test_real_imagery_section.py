"""The [data.real_imagery] section and data.coil_root: defaults, ranges and cross-key checks."""
from __future__ import annotations

import pytest

from pipeline.infra.config import ConfigError, load_config
from tests.conftest import ROOT

REAL = ROOT / "configs" / "real.toml"


def test_real_config_loads_with_its_paths_beside_the_project():
    cfg = load_config(REAL)
    assert cfg.data.source == "real_imagery" and cfg.classifier.arch == "efficientnet_lite0"
    assert cfg.path("data.coil_root").resolve() == (ROOT.parent / "shared" / "realdata" / "coil100").resolve()
    assert cfg.data.real_imagery.train_step_deg == 10 and cfg.models.dirichlet.entries == 4


@pytest.mark.parametrize("over,match", [
    ({"data": {"real_imagery": {"train_step_deg": 25}}}, "train_step_deg"),
    ({"data": {"real_imagery": {"train_step_deg": 5}}}, "train_step_deg"),
    ({"data": {"real_imagery": {"objects": [3, 3]}}}, "objects"),
    ({"data": {"real_imagery": {"objects": [0, 3]}}}, "objects"),
    ({"data": {"coil_root": ""}}, "coil_root"),
    ({"models": {"dirichlet": {"entries": 5}}}, "entries"),
    ({"data": {"real_imagery": {"noise": 1.0}}}, "noise"),
])
def test_bad_keys_are_named(over, match):
    with pytest.raises(ConfigError, match=match):
        load_config(REAL, over)
