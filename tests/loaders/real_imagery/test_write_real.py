"""The real-imagery writer on the real data (two COIL objects, one real AVD scan): every framed box
is the object's own box fitted into a real box, shows the held-out COIL view nearest the real
bearing, scaled uniformly into that box."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tests.loaders.realdata import need


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.config import load_config
    from tests.conftest import ROOT

    real = need("coil100").parent
    out = tmp_path_factory.mktemp("ri")
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(out / "artifacts")},
        "data": {"coil_root": str(real / "coil100"), "avd_root": str(need("avd")), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1"],
                 "real_imagery": {"objects": [2, 3], "noise_std": 0.0, "blur_sigma_px": 0.0, "jpeg_quality": 100}},
        "evaluate": {"n_candidates": 2}})
    write_real_imagery(cfg, out / "bigbird", out / "avd", out / "truth.json", SkipPolicy(True))
    return cfg, out, real


def test_framed_boxes_show_the_nearest_heldout_view(written):
    from loaders.avd import AVDScan
    from loaders.coil import CoilFolder
    from loaders.real_imagery.frames import (
        nearest_view,
        object_bearing_deg,
        resampled_view,
    )

    _, out, real = written
    truth = json.loads((out / "truth.json").read_text())["scans"]["Home_005_1"]["instances"]
    assert sorted(truth) == ["coil_obj002", "coil_obj003"]
    ours = AVDScan(out / "avd", "Home_005_1")
    src = AVDScan(real / "avd", "Home_005_1", frames=False)
    coil = CoilFolder(real / "coil100")
    held = [a for a in range(5, 360, 10)]
    checked = 0
    for name, img in sorted(ours.images.items()):
        for b in img.boxes:
            obj = ours.instance_names[b.instance_id]
            rec = truth[obj]
            rid = src.instance_ids[rec["avd_instance"]]
            # the written box is the object's own, inside a real box of its instance and centred on it
            assert any(r.instance_id == rid and r.x0 <= b.x0 and b.x1 <= r.x1 and r.y0 <= b.y0 and b.y1 <= r.y1
                       and abs((r.x0 + r.x1) - (b.x0 + b.x1)) <= 1 and abs((r.y0 + r.y1) - (b.y0 + b.y1)) <= 1
                       and ((b.x0, b.x1) == (r.x0, r.x1) or (b.y0, b.y1) == (r.y0, r.y1))
                       for r in src.images[name].boxes)
            bear = float(object_bearing_deg(img.position[None], np.array(rec["position"]), rec["yaw_deg"])[0])
            a = nearest_view(bear, held)
            assert a % 10 == 5 and a in rec["heldout_views_used"]
            if checked < 6 and min(b.x1 - b.x0, b.y1 - b.y0) >= 24:
                frame = ours.read_image(name)[b.y0:b.y1, b.x0:b.x1].astype(float)
                errs = {}
                bw, bh = b.x1 - b.x0, b.y1 - b.y0
                _, shown = coil.read(coil.view(rec["coil_object"], a))
                m, (dx, dy) = resampled_view(shown.astype(np.uint8) * 255, shown, bw, bh)
                # the object's own pixels only: the box's corners are the frame's surround (clutter), the
                # object is cut out by its mask (the silhouette eroded off its resampled edge)
                inside = cv2.erode((m[dy:dy + bh, dx:dx + bw] == 255).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
                for cand in (a, (a + 90) % 360, (a + 180) % 360):
                    rgb, mask = coil.read(coil.view(rec["coil_object"], cand))
                    patch, (dx, dy) = resampled_view(rgb, mask, bw, bh)
                    errs[cand] = np.abs(patch[dy:dy + bh, dx:dx + bw] - frame)[inside].mean()
                # < 5 grey levels (JPEG's chroma subsampling on colour edges) against 20-30 for other views
                assert errs[a] < 5.0 and errs[a] == min(errs.values()), (name, len(img.boxes), errs)
                checked += 1
    assert checked == 6
    # the training side holds training views only
    angles = sorted(int(p.stem.split("_")[1]) for p in (out / "bigbird" / "coil_obj002").glob("NP1_*.jpg"))
    assert angles == list(range(0, 360, 10))
