"""Category-level classes on ETH-80 through the whole chain (data -> classifier -> features ->
models -> evaluate -> report), small: 3 categories x 3 instance folds on one real AVD scan. The
no-leak checks: a held-out instance's photographs never reach its fold's training folders, fits or
component choice, and every scored frame shows it. Skips where ../shared/realdata is absent."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.loaders.realdata import need

pytestmark = pytest.mark.slow  # real stages on real data (make test-fast skips it)

SMALL = {
    "data": {"scans": ["Home_005_1"], "real_imagery": {"categories": ["apple", "car", "cup"], "instances": [1, 2, 3]}},
    "features": {"n_samples": 3, "bigbird_samples": 3},
    "models": {"restarts": 0, "dirichlet": {"entries": 3}, "n_components": 3, "targets": "deterministic"},
    "evaluate": {"track_length": 5, "tracks_per_target": 1, "n_candidates": 3, "bootstrap": 200,
                 "ablations": [], "attribution": True, "experiments": ["biased", "randomized"],
                 "biased": {"n_loc_samples": 5},
                 "randomized": {"sigmas_m": [0.3], "realizations": 3, "n_loc_samples": 5}},
    "plan": {"enabled": False},
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from pipeline.infra.config import load_config, merge
    from stages.framework.runner import ensure
    from tests.conftest import ROOT

    real = need("eth80").parent
    tmp = tmp_path_factory.mktemp("cat")
    over = merge({"run": {"artifacts": str(tmp / "artifacts"), "device": "cpu"},
                  "data": {"eth80_root": str(real / "eth80"), "avd_root": str(need("avd"))}}, SMALL)
    cfg = load_config(ROOT / "configs" / "real_category.toml", over)
    keys: dict = {}
    ensure(cfg, "evaluate", device="cpu", _keys=keys)
    ensure(cfg, "report", device="cpu", _keys=keys)
    return cfg, real / "eth80"


def _fold(cls: str) -> int:
    return int(cls.rpartition("__f")[2])


def test_training_folders_hold_only_the_other_instances(run):
    from loaders.eth80 import Eth80Folder

    cfg, root = run
    bb = cfg.stage_dir("data") / "bigbird"
    eth = Eth80Folder(root)
    checked = 0
    for folder in sorted(p for p in bb.iterdir() if p.is_dir()):
        cat, f = folder.name.rpartition("__f")[0], _fold(folder.name)
        codes = sorted(int(p.stem.split("_")[1]) for p in folder.glob("NP1_*.jpg"))
        assert sorted({c // 360 for c in codes}) == sorted({1, 2, 3} - {f})      # never instance f
        assert len(codes) == 2 * 16                                            # several photographs per azimuth
        for code in codes[::11]:   # the code tells the truth: the file is that instance's photograph
            rgb, _, _ = eth.read_instance(cat, code // 360)[min(eth.read_instance(cat, code // 360),
                                                                 key=lambda a: abs(round(a) - code % 360))]
            got = cv2.imread(str(folder / f"NP1_{code}.jpg"))[:, :, ::-1].astype(float)
            assert np.abs(got - rgb).mean() < 4.0
            checked += 1
    assert checked >= 9


def test_fits_and_component_choice_never_see_the_target(run):
    from pipeline.evaluation.grid.candidates import plan_components

    cfg, _ = run
    feats = pq.read_table(cfg.stage_dir("features") / "bigbird.parquet").to_pandas()
    det = feats[feats["pass"] == -1]
    for obj, d in det.groupby("object"):
        assert _fold(obj) not in set(d["angle_deg"] // 360)                 # fitted views: other instances
    index = json.loads((cfg.stage_dir("models") / "index.json").read_text())
    plan = index["candidate_sets"]
    assert len(plan) == 9
    for target, p in plan.items():
        assert {_fold(c) for c in p["classes"]} == {_fold(target)}           # candidates from its own fold
        # The component choice is a function of its candidates' training scores alone: recomputed
        # from the fold's rows (which hold no view of instance f), it is the one the bank uses.
        scores = {c: np.stack(det[det["object"] == c].sort_values("angle_deg")["scores"].to_numpy())
                  for c in p["classes"]}
        again = plan_components({target: p["classes"]}, scores, cfg.models.n_components, cfg.models.component_rule,
                                cfg.models.components, cfg.models.informative_min)
        assert again[target]["components"] == p["components"]


def test_frames_show_the_held_out_instance_and_every_method_runs(run):
    cfg, _ = run
    truth = json.loads((cfg.stage_dir("data") / "truth.json").read_text())
    inst = truth["scans"]["Home_005_1"]["instances"]
    assert sorted(inst) == sorted(f"{c}__f{f}" for c in ("apple", "car", "cup") for f in (1, 2, 3))
    for cls, rec in inst.items():
        assert rec["eth80_instance"] == _fold(cls) and rec["category"] == cls.rpartition("__f")[0]
        assert rec["max_view_offset_deg"] <= 11.25 + 1e-6
        assert _fold(cls) not in truth["folds"][str(_fold(cls))]["classes"][cls]   # its class never saw it
    ev = cfg.stage_dir("evaluate")
    df = pq.read_table(ev / "results.parquet").to_pandas()
    assert {"with_uncertainty", "model_based", "simple_bayes", "dirichlet"} <= set(df["method"])
    assert json.loads((ev / "summary.json").read_text())["population"]["n_targets"] >= 6
    assert (cfg.stage_dir("report") / "index.html").is_file()
