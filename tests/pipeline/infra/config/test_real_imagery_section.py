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


CATEGORY = ROOT / "configs" / "real_category.toml"


@pytest.mark.parametrize("path,over,match", [
    (CATEGORY, {"data": {"real_imagery": {"class_level": "instance"}}}, r"class_level' = 'instance' needs .*view_split"),
    (CATEGORY, {"data": {"avd_frames_root": "", "real_imagery": {"train_background": "avd_frames"}}},
     r"'data.real_imagery.train_background' = 'avd_frames' needs 'data.avd_frames_root'"),
    (CATEGORY, {"data": {"real_imagery": {"train_background": "cloth"}}}, "train_background"),
    (REAL, {"data": {"real_imagery": {"background": "avd_frames"}}}, "COIL-100 photographs are on black"),
    (REAL, {"data": {"real_imagery": {"train_background": "avd_frames"}}}, "COIL-100 photographs are on black"),
    (REAL, {"data": {"real_imagery": {"view_split": "alternate"}}}, "are for dataset = 'eth80'"),
])
def test_background_and_level_keys_are_checked(path, over, match):
    with pytest.raises(ConfigError, match=match):
        load_config(path, over)


def test_the_contrast_config_differs_from_its_instance_arm_in_one_key():
    cat = load_config(ROOT / "configs" / "real_contrast.toml")
    ins = load_config(ROOT / "configs" / "real_contrast.toml", {"data": {"real_imagery": {"class_level": "instance"}}})
    ri = cat.data.real_imagery
    assert (ri.view_split, ri.class_level, ri.max_view_error_deg, ri.train_background) == ("alternate", "category", 22.5, "same")
    assert ins.data.real_imagery.class_level == "instance"
    assert {k: v for k, v in vars(ri).items() if k != "class_level"} == \
        {k: v for k, v in vars(ins.data.real_imagery).items() if k != "class_level"}
