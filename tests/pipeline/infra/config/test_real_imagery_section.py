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
    # COIL objects are cut out by their own mask, so they may stand in clutter (real.toml does): the
    # clutter needs its frames
    (REAL, {"data": {"avd_frames_root": ""}}, r"'data.real_imagery.background' = 'avd_frames' needs 'data.avd_frames_root'"),
    (REAL, {"data": {"avd_frames_root": "", "real_imagery": {"background": "black", "train_background": "avd_frames"}}},
     r"'data.real_imagery.train_background' = 'avd_frames' needs 'data.avd_frames_root'"),
    (REAL, {"data": {"real_imagery": {"view_split": "alternate"}}}, "are for dataset = 'eth80'"),
])
def test_background_and_level_keys_are_checked(path, over, match):
    with pytest.raises(ConfigError, match=match):
        load_config(path, over)


def test_the_contrast_config_runs_both_arms_in_one_run():
    from loaders.real_imagery.category import class_members, contrast_members

    cfg = load_config(ROOT / "configs" / "real_contrast.toml")
    ri = cfg.data.real_imagery
    assert (ri.view_split, ri.class_level, ri.contrast, ri.max_view_error_deg, ri.train_background) == \
        ("alternate", "category", True, 22.5, "same")
    # the arms: the same classes, fitted on the other instances (category) or on the instance itself
    truth = {"classes": {"car__f2": ["eth80_car1", "eth80_car3"], "cup__f10": ["eth80_cup1"]}}
    assert class_members(cfg, truth) == truth["classes"]
    assert contrast_members(cfg, truth) == {"car__f2": ["eth80_car2"], "cup__f10": ["eth80_cup10"]}
    assert set(contrast_members(cfg)) == set(class_members(cfg))          # without a record: the config's classes
    assert contrast_members(load_config(CATEGORY), truth) is None


@pytest.mark.parametrize("over,match", [
    ({"data": {"real_imagery": {"class_level": "instance"}}}, "contrast' = true needs 'class_level' = 'category'"),
    ({"data": {"real_imagery": {"view_split": "none"}}}, "contrast' = true needs .*'view_split' = 'alternate'"),
    ({"evaluate": {"test_domain_variance": "cross_fit"}}, "contrast' = true needs 'evaluate.test_domain_variance'"),
])
def test_the_contrast_keys_are_checked(over, match):
    with pytest.raises(ConfigError, match=match):
        load_config(ROOT / "configs" / "real_contrast.toml", over)
    with pytest.raises(ConfigError, match="'contrast' are for dataset = 'eth80'"):
        load_config(REAL, {"data": {"real_imagery": {"contrast": True}}})
