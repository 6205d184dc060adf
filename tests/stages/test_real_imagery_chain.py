"""A small COIL-100 subset on one real AVD scan through the whole chain (data -> classifier ->
features -> models -> evaluate -> report) with configs/real.toml's network: every frame shows a
held-out view, each box is the object's own fitted into a real one, and the population has every method. Skips where
../shared/realdata is absent."""
from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest

from tests.loaders.realdata import need

pytestmark = pytest.mark.slow  # real stages on real data (make test-fast skips it)

SMALL = {
    "report": {"strict": "all"},   # tests and CI: a figure-text slip fails the build too
    "data": {"scans": ["Home_005_1"],
             "real_imagery": {"objects": [2, 3, 4, 5, 6]}},
    "features": {"n_samples": 3, "bigbird_samples": 3},
    "models": {"restarts": 0, "dirichlet": {"entries": 3}, "n_components": 3},
    "evaluate": {"track_length": 5, "tracks_per_target": 2, "n_candidates": 3, "bootstrap": 200,
                 "ablations": [], "attribution": True,
                 "biased": {"n_loc_samples": 5},
                 "randomized": {"sigmas_m": [0.1, 0.3], "realizations": 4, "n_loc_samples": 5},
                 "sensitivity": {"sigmas_m": [0.1], "realizations": 3, "n_loc_samples": 4},
                 "bias_maps": {"steps": 5}},
}


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    from pipeline.infra.config import load_config, merge
    from stages.framework.runner import ensure
    from tests.conftest import ROOT

    real = need("coil100").parent
    tmp = tmp_path_factory.mktemp("real")
    over = merge({"run": {"artifacts": str(tmp / "artifacts"), "device": "cpu"},
                  "data": {"coil_root": str(real / "coil100"), "avd_root": str(real / "avd"),
                           "avd_frames_root": str(real / "avd_frames")}}, SMALL)
    cfg = load_config(ROOT / "configs" / "real.toml", over)
    keys: dict = {}
    ensure(cfg, "evaluate", device="cpu", _keys=keys)
    ensure(cfg, "report", device="cpu", _keys=keys)
    return cfg


def test_frames_are_heldout_views_at_the_real_boxes(real_run):
    from loaders.avd import AVDScan

    data = real_run.stage_dir("data")
    truth = json.loads((data / "truth.json").read_text())
    inst = truth["scans"]["Home_005_1"]["instances"]
    assert len(inst) == 5 and truth["pairing"].startswith("synthetic")
    for name, rec in inst.items():
        assert rec["heldout_views_used"] and all(a % 10 == 5 for a in rec["heldout_views_used"])  # never training
    real = AVDScan(need("avd"), "Home_005_1", frames=False)
    ours = AVDScan(data / "avd", "Home_005_1")
    n = 0
    for name, img in ours.images.items():
        for b in img.boxes:
            real_inst = inst[ours.instance_names[b.instance_id]]["avd_instance"]
            rid = real.instance_ids[real_inst]
            # the object's own box, scaled uniformly into a real box of its instance and centred in it
            assert any(r.instance_id == rid and r.x0 <= b.x0 and b.x1 <= r.x1 and r.y0 <= b.y0 and b.y1 <= r.y1
                       and abs((r.x0 + r.x1) - (b.x0 + b.x1)) <= 1 and abs((r.y0 + r.y1) - (b.y0 + b.y1)) <= 1
                       and ((b.x0, b.x1) == (r.x0, r.x1) or (b.y0, b.y1) == (r.y0, r.y1))
                       for r in real.images[name].boxes)
            pix = ours.read_image(name)[b.y0:b.y1, b.x0:b.x1]
            assert pix.max() > 60            # the pasted photograph is there
            n += 1
    assert n > 20
    np_ = pytest.importorskip("numpy")
    np_.testing.assert_allclose(ours.images[name].position, real.images[name].position)


def test_population_has_every_method(real_run):
    ev = real_run.stage_dir("evaluate")
    df = pq.read_table(ev / "results.parquet").to_pandas()
    summary = json.loads((ev / "summary.json").read_text())
    pop = summary["population"]
    assert pop["n_targets"] >= 3
    assert {"with_uncertainty", "model_based", "simple_bayes", "dirichlet"} <= set(df["method"])
    assert set(df["experiment"]) >= {"biased", "randomized"}
    assert (real_run.stage_dir("report") / "index.html").is_file()
