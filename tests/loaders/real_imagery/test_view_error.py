"""The frames' viewpoint error: measured per frame, bounded by data.real_imagery.max_view_error_deg
(frames beyond it refused and counted), its distribution in truth.json and the data manifest."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from tests.conftest import ROOT
from tests.loaders.realdata import need


@pytest.mark.parametrize("bearing,angle,err", [(3.0, 5, 2.0), (359.0, 5, 6.0), (10.0, 5, 5.0), (180.0, 0, 180.0),
                                               (355.0, 355, 0.0)])
def test_view_error_is_circular(bearing, angle, err):
    from loaders.real_imagery.frames import view_error_deg

    assert float(view_error_deg(bearing, angle)) == pytest.approx(err)


def test_summary_counts_the_frames_beyond_the_bound():
    from loaders.real_imagery.scans import view_error_summary

    e = [0.5, 1.0, 2.6, 4.9, 5.1, 8.7]
    s = view_error_summary(e, 5.0)
    assert s["frames"] == 6 and s["refused"] == 2 and s["max"] == 8.7 and s["bound"] == 5.0
    assert s["share_over_2_5"] == pytest.approx(4 / 6, abs=1e-4) and s["share_over_5"] == pytest.approx(2 / 6, abs=1e-4)
    assert view_error_summary([], 5.0) == {"frames": 0, "refused": 0, "bound": 5.0}


def _write(tmp_path, bound: float, sparse: bool):
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.config import load_config

    coil = need("coil100")
    mine = tmp_path / "coil"
    mine.mkdir()
    for k in (2, 3):
        for p in coil.glob(f"obj{k}__*.png"):
            a = int(p.stem.split("__")[1])
            if sparse and k == 3 and a % 10 and a not in (5, 185):  # object 3 keeps two held-out views
                continue
            shutil.copy(p, mine)
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(tmp_path / "art")},
        "data": {"coil_root": str(mine), "avd_root": str(need("avd")), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1"],
                 "real_imagery": {"objects": [2, 3], "max_view_error_deg": bound}},
        "evaluate": {"n_candidates": 2}})
    extra, _ = write_real_imagery(cfg, tmp_path / "bb", tmp_path / "avd", tmp_path / "truth.json", SkipPolicy(True))
    return extra, json.loads((tmp_path / "truth.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("bound,sparse", [(10.0, False), (2.5, False), (10.0, True)])
def test_frames_beyond_the_bound_are_refused_and_counted(tmp_path, bound, sparse):
    extra, truth = _write(tmp_path, bound, sparse)
    ve = truth["view_error_deg"]
    assert extra["view_error_deg"] == ve and ve["bound"] == bound
    inst = truth["scans"]["Home_005_1"]["instances"]
    refused = sum(r["frames_refused_view_error"] for r in inst.values())
    written = sum(r["frames"] for r in inst.values())
    assert ve["refused"] == refused and ve["frames"] == refused + written
    assert ve["refused"] == (0 if bound >= 5.0 and not sparse else ve["refused"])
    if bound < 5.0 or sparse:
        assert ve["refused"] > 0 and ve["max"] > bound
    else:
        assert ve["max"] <= 5.0  # every held-out view of objects 2 and 3 is there: half the 10-degree spacing
    # the frames that were written are within the bound: their views are the nearest, within it
    from loaders.avd import AVDScan
    from loaders.real_imagery.frames import object_bearing_deg, view_error_deg
    ours = AVDScan(tmp_path / "avd", "Home_005_1")
    errs = []
    for img in ours.images.values():
        for b in img.boxes:
            rec = inst[ours.instance_names[b.instance_id]]
            bear = float(object_bearing_deg(img.position[None], np.array(rec["position"]), rec["yaw_deg"])[0])
            errs.append(min(float(view_error_deg(bear, a)) for a in rec["heldout_views_used"]))
    assert len(errs) == written and (not errs or max(errs) <= bound + 1e-9)
