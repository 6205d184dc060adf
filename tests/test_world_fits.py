"""On a small generated stand-in world, the GP fits mean something: no component whose training
scores vary over the views ends at a hyperparameter bound (tests/world_checks.py)."""
import pyarrow.parquet as pq
import pytest

from tests.world_checks import bound_report

SMALL = {
    "data": {"synthetic": {"angle_step_deg": 9, "bigbird_width": 320, "bigbird_height": 256,
                           "avd_width": 192, "avd_height": 108, "grid_step_m": 0.6, "distractors": 2,
                           "workers": 1}},
    "classifier": {"input_size": 64, "training": {"train_images": 240, "val_images": 24, "epochs": 2,
                                                  "batch_size": 24, "min_accuracy": 0.0}},
    "features": {"n_samples": 2, "bigbird_samples": 0, "max_difficulty": 5, "batch_size": 64},
    "models": {"restarts": 1},
}


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from pipeline.config import _merge, load_config
    from stages.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    art = tmp_path_factory.mktemp("world") / "artifacts"
    cfg = load_config(DEFAULT_CONFIG, _merge(SMALL, {"run": {"artifacts": str(art), "device": "cpu"}}))
    ensure(cfg, "models", device="cpu")
    return cfg


def test_no_varying_component_ends_at_a_bound(world):
    rep = bound_report(world.stage_dir("models"), world.stage_dir("features"))
    assert rep["n_fits"] > 0 and rep["n_varying"] > 0  # the check is not vacuous
    bad = [(f["class"], f["name"], round(f["train_std"], 4), f["at_bound"]) for f in rep["varying_at_bound"]]
    assert bad == []


def test_features_cover_every_scan(world):
    scans = set(pq.read_table(world.stage_dir("features") / "avd.parquet", columns=["scan"])
                .column("scan").to_pylist())
    assert scans == set(world.data.scans) and len(scans) == 2
