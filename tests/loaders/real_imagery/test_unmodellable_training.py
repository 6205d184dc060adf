"""Training sides that cannot be modelled are refused early, naming the object and the count: by
the config check (a step too coarse for models.min_views) or by the data stage (an object with too
few readable views); the models stage names classes as plain strings."""
from __future__ import annotations

import shutil

import pytest

from tests.conftest import ROOT
from tests.loaders.realdata import need


@pytest.mark.parametrize("step,min_views,ok", [(180, 8, False), (60, 8, False), (90, 8, False), (45, 8, True),
                                               (90, 4, True), (120, 4, False), (10, 40, False)])
def test_config_refuses_a_step_that_cannot_reach_min_views(tmp_path, step, min_views, ok):
    from pipeline.infra.config import ConfigError, load_config

    over = {"run": {"artifacts": str(tmp_path)}, "data": {"real_imagery": {"train_step_deg": step}},
            "models": {"min_views": min_views}}
    if ok:
        load_config(ROOT / "configs" / "real.toml", over)
        return
    with pytest.raises(ConfigError, match=rf"train_step_deg' = {step} gives each object {360 // step} training "
                                          rf"views, fewer than 'models.min_views' = {min_views}"):
        load_config(ROOT / "configs" / "real.toml", over)


@pytest.mark.parametrize("keep", [1, 5])
def test_data_stage_refuses_an_object_with_too_few_views(tmp_path, keep):
    from loaders.errors import BadInputError, SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.config import load_config

    coil, avd = need("coil100"), need("avd")
    mine = tmp_path / "coil"
    mine.mkdir()
    for k in (2, 3):
        for p in coil.glob(f"obj{k}__*.png"):
            shutil.copy(p, mine)
    for a in list(range(0, 360, 10))[:keep] + [5]:  # a few training views of object 4, one held-out
        shutil.copy(coil / f"obj4__{a}.png", mine)
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(tmp_path / "art")},
        "data": {"coil_root": str(mine), "avd_root": str(avd), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1"], "skip_bad_views": False,
                 "real_imagery": {"objects": [2, 3, 4]}}, "evaluate": {"n_candidates": 3}})
    with pytest.raises(BadInputError, match=rf"obj4__0.png: coil_obj004: {keep} readable training views? at "
                                            r"data.real_imagery.train_step_deg = 10, fewer than models.min_views = 8"):
        write_real_imagery(cfg, tmp_path / "bb", tmp_path / "avd", tmp_path / "truth.json", SkipPolicy(False))


def test_models_stage_names_classes_as_plain_strings(tmp_path):
    from pipeline.banks.model_bank import FeaturesError, fit_from_features
    from tests.stages.test_models_stage import mcfg, write_features

    p = tmp_path / "bigbird.parquet"
    write_features(p, n_angles=6)
    with pytest.raises(FeaturesError) as e:
        fit_from_features(p, mcfg(classes="all"), progress=False)
    assert "np.str_" not in str(e.value) and "6 training views" in str(e.value)
