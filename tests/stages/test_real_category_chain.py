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


def small_chain(tmp_path_factory, config: str, extra: dict | None = None):
    """``configs/<config>`` at SMALL (and ``extra``) on the real ETH-80 and AVD copies, run through
    evaluate and report; returns the config."""
    from pipeline.infra.config import load_config, merge
    from stages.framework.runner import ensure
    from tests.conftest import ROOT

    real = need("eth80").parent
    tmp = tmp_path_factory.mktemp(config.split(".")[0])
    over = merge(merge({"run": {"artifacts": str(tmp / "artifacts"), "device": "cpu"},
                        "data": {"eth80_root": str(real / "eth80"), "avd_root": str(need("avd"))}}, SMALL), extra or {})
    cfg = load_config(ROOT / "configs" / config, over)
    keys: dict = {}
    ensure(cfg, "evaluate", device="cpu", _keys=keys)
    ensure(cfg, "report", device="cpu", _keys=keys)
    return cfg


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return small_chain(tmp_path_factory, "real_category.toml"), need("eth80")


def _fold(cls: str) -> int:
    return int(cls.rpartition("__f")[2])


def test_training_views_are_the_instances_photographs(run):
    from loaders.eth80 import Eth80Folder
    from loaders.real_imagery.clutter import training_view

    cfg, root = run
    bb = cfg.stage_dir("data") / "bigbird"
    eth = Eth80Folder(root)
    folders = sorted(p.name for p in bb.iterdir() if p.is_dir())
    assert folders == sorted(f"eth80_{c}{i}" for c in ("apple", "car", "cup") for i in (1, 2, 3))   # each once
    checked = 0
    for name in folders:
        cat, inst = name[6:-1], int(name[-1])
        photos = eth.read_instance(cat, inst)
        codes = sorted(int(p.stem.split("_")[1]) for p in (bb / name).glob("NP1_*.jpg"))
        assert len(codes) == 16 and {c // 360 for c in codes} == {inst}
        for code in codes[::5]:   # the code tells the truth: the file is that azimuth's photograph,
            # cut out onto black as the frames are (data.real_imagery.train_background = "same")
            rgb, _, alpha = photos[min(photos, key=lambda a: abs(round(a) - code % 360))]
            got = cv2.imread(str(bb / name / f"NP1_{code}.jpg"))[:, :, ::-1].astype(float)
            # extended by one border on every side, so that no training crop runs off it
            # (clutter.on_surround), the border black like the rest of the surround
            b = (got.shape[0] - rgb.shape[0]) // 2
            assert b >= 0 and got.shape[:2] == (rgb.shape[0] + 2 * b, rgb.shape[1] + 2 * b)
            rgb = training_view(np.pad(rgb, ((b, b), (b, b), (0, 0))), np.pad(np.asarray(alpha, np.float32), b),
                                "black", None, None)
            assert np.abs(got - rgb).mean() < 4.0
            checked += 1
    assert checked >= 27


def test_fits_and_component_choice_never_see_the_target(run):
    from pipeline.evaluation.grid.candidates import plan_components

    cfg, _ = run
    feats = pq.read_table(cfg.stage_dir("features") / "bigbird.parquet").to_pandas()
    det = feats[feats["pass"] == -1]
    index = json.loads((cfg.stage_dir("models") / "index.json").read_text())
    fitted = index["training_angles_deg"]            # per class: the view codes its GPs were fitted on
    assert len(fitted) == 9
    for cls, codes in fitted.items():
        assert {c // 360 for c in codes} == {1, 2, 3} - {_fold(cls)} and len(codes) == 2 * 16
    plan = index["candidate_sets"]
    assert len(plan) == 9
    for target, p in plan.items():
        assert {_fold(c) for c in p["classes"]} == {_fold(target)}           # candidates from its own fold
        # The component choice is a function of its candidates' training scores alone: recomputed
        # from the fold's rows (which hold no view of instance f), it is the one the bank uses.
        scores = {}
        for c in p["classes"]:
            cat = c.rpartition("__f")[0]
            rows = det[det["object"].isin([f"eth80_{cat}{i}" for i in (1, 2, 3) if i != _fold(c)])]
            scores[c] = np.stack(rows.sort_values("angle_deg", kind="stable")["scores"].to_numpy())
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
