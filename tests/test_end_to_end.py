"""The whole chain on a tiny configuration: data -> classifier -> features -> models -> evaluate ->
report, through the same runner the CLI uses. Small sizes keep it to about a minute."""
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

TINY = {
    "data": {"scans": ["Home_001_1"], "synthetic": {"instances_per_scan": 0, "angle_step_deg": 30, "bigbird_width": 200, "bigbird_height": 160,
                           "avd_width": 480, "avd_height": 270}},
    "classifier": {"input_size": 64,
                   "training": {"train_images": 48, "val_images": 24, "epochs": 1, "batch_size": 16,
                                "min_accuracy": 0.0}},
    "features": {"n_samples": 3, "max_difficulty": 5, "batch_size": 32},
    "models": {"restarts": 0},
    "evaluate": {"track_length": 4, "max_difficulty": 5,
                 "biased": {"n_loc_samples": 5},
                 "randomized": {"realizations": 6, "n_loc_samples": 5},
                 "sensitivity": {"sigmas_m": [0.1, 0.4], "realizations": 3, "n_loc_samples": 4},
                 "bias_maps": {"steps": 5}},
}


@pytest.fixture(scope="module")
def run_all(tmp_path_factory):
    from pipeline.config import _merge, load_config
    from stages.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    tmp = tmp_path_factory.mktemp("e2e")
    cfg = load_config(DEFAULT_CONFIG, _merge({"run": {"artifacts": str(tmp / "artifacts"), "device": "cpu"}}, TINY))
    keys: dict = {}
    ensure(cfg, "evaluate", device="cpu", _keys=keys)
    ensure(cfg, "report", device="cpu", _keys=keys)
    return cfg


def test_every_stage_wrote_its_manifest(run_all):
    from stages.runner import read_manifest
    for stage in ("data", "classifier", "features", "models", "evaluate", "report"):
        m = read_manifest(run_all, stage)
        assert m is not None and m["key"], stage


def test_results_cover_the_experiments(run_all):
    cfg = run_all
    ev = cfg.stage_dir("evaluate")
    t = pq.read_table(ev / "results.parquet")
    df = t.to_pandas()
    meta = {k.decode(): v.decode() for k, v in t.schema.metadata.items()}
    classes = json.loads(meta["viewfuse.classes"])
    assert classes == list(cfg.models.classes) and meta["viewfuse.target"] == cfg.evaluate.target
    assert set(df["experiment"]) == {"biased", "randomized", "sensitivity"}
    assert set(df["method"]) == {"with_uncertainty", "model_based"}
    rnd = df[df["experiment"] == "randomized"]
    assert len(rnd) == 6 * 4 * 2
    post = np.stack(df["posterior"].to_numpy())
    np.testing.assert_allclose(post.sum(1), 1.0, atol=1e-9)
    assert np.isfinite(df["log_mgr"]).all() and (df["log_mgr"] >= 0).all()
    track = json.loads((ev / "track.json").read_text())
    assert len(track["images"]) == 4 and len(set(track["images"])) == 4
    assert track["localization_error_m"] < 0.05
    for name in ("gp_models.npz", "bias_maps.npz", "summary.json"):
        assert (ev / name).is_file(), name


def test_report_references_existing_figures(run_all):
    import re
    rep = run_all.stage_dir("report")
    html = (rep / "index.html").read_text()
    imgs = re.findall(r'<img[^>]+src="([^"]+)"', html)
    assert len(imgs) >= 5
    for src in imgs:
        assert (rep / src).is_file(), src
    assert 'class="summary' in html


def test_rerun_is_skipped_and_deterministic(run_all, capsys):
    from stages.runner import ensure, read_manifest
    cfg = run_all
    before = read_manifest(cfg, "evaluate")
    res_before = (cfg.stage_dir("evaluate") / "results.parquet").read_bytes()
    ensure(cfg, "evaluate", device="cpu")
    assert read_manifest(cfg, "evaluate") == before
    assert "up to date" in capsys.readouterr().out
    # Forced rerun: same seed, same numbers.
    ensure(cfg, "evaluate", device="cpu", force=True)
    a = pq.read_table(cfg.stage_dir("evaluate") / "results.parquet").to_pandas()
    import io
    b = pq.read_table(io.BytesIO(res_before)).to_pandas()
    np.testing.assert_array_equal(np.stack(a["posterior"]), np.stack(b["posterior"]))
