"""No written frame deforms its object: the photograph is scaled uniformly into its real box
(``frames.fit_in_box``), centred, and the written box is the object's own. Read back from the
frames, the object's aspect ratio is the source mask's within 2 %, however different the real
box's aspect ratio is."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from loaders.real_imagery.frames import fit_in_box, mask_bbox, render_frame
from tests.conftest import ROOT
from tests.loaders.realdata import need

OBJ_W, OBJ_H = 80, 50            # the generated object's mask box: aspect 1.6
COLOUR = (200, 180, 20)


def _photo(w=OBJ_W, h=OBJ_H):
    """A generated turntable photograph: a flat object of known box on COIL's black."""
    rgb = np.zeros((128, 128, 3), np.uint8)
    y0, x0 = (128 - h) // 2, (128 - w) // 2
    rgb[y0:y0 + h, x0:x0 + w] = COLOUR
    return rgb, rgb.max(axis=2) > 40


def _aspect_read_back(frame, box):
    """The object's aspect ratio segmented from a frame near ``box`` (not black: the known background)."""
    x0, y0, x1, y1 = box
    m = max(x1 - x0, y1 - y0)
    win = frame[max(y0 - m, 0):y1 + m, max(x0 - m, 0):x1 + m]
    seg = win[:, :, 0] > COLOUR[0] / 2          # half the object's level: the resampled edge splits evenly
    bx0, by0, bx1, by1 = mask_bbox(seg)
    return (bx1 - bx0) / (by1 - by0)


@pytest.mark.parametrize("bw,bh", [(400, 100), (100, 400), (300, 300), (640, 160), (120, 90), (90, 300)])
def test_uniform_fit_keeps_the_aspect_ratio(bw, bh):
    rgb, mask = _photo()
    real = (600, 300, 600 + bw, 300 + bh)
    obj, scale, fill = fit_in_box(mask, real)
    ow, oh = obj[2] - obj[0], obj[3] - obj[1]
    assert (ow == bw or oh == bh) and ow <= bw and oh <= bh                  # fits, one side fills the box
    assert abs((obj[0] + obj[2]) - (real[0] + real[2])) <= 1 and abs((obj[1] + obj[3]) - (real[1] + real[3])) <= 1
    assert scale == pytest.approx(min(bw / OBJ_W, bh / OBJ_H))
    assert fill == pytest.approx(ow * oh / (bw * bh)) and 0 < fill <= 1
    frame = render_frame((1920, 1080), [(rgb, mask, obj)], 0.0, 0.0, np.random.default_rng(0))
    got = _aspect_read_back(frame, obj)
    assert got == pytest.approx(OBJ_W / OBJ_H, rel=0.02), (bw, bh, got)
    if bw / bh > 2 or bh / bw > 2:
        assert fill < 0.9                      # the old per-axis scaling would have filled it: stretched


def test_written_frames_keep_the_source_aspect_ratio(tmp_path):
    """Through the writer: generated photographs (aspect 1.6 and 0.5) on the real boxes of a real
    AVD scan, whose aspect ratios vary widely; every object read back from a written frame keeps
    its photograph's aspect ratio within 2 % (boxes large enough to measure it to that)."""
    from loaders.avd import AVDScan
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.config import load_config

    avd = need("avd")
    coil = tmp_path / "coil"
    coil.mkdir()
    shapes = {2: (80, 50), 3: (40, 80)}
    for k, (w, h) in shapes.items():
        rgb, _ = _photo(w, h)
        for a in range(0, 360, 5):
            cv2.imwrite(str(coil / f"obj{k}__{a}.png"), rgb[:, :, ::-1])
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(tmp_path / "art")},
        "data": {"coil_root": str(coil), "avd_root": str(avd), "scans": ["Home_005_1"],
                 "real_imagery": {"objects": [2, 3], "noise_std": 0.0, "blur_sigma_px": 0.0, "jpeg_quality": 100,
                                  "frames": "all", "background": "black"}},   # read back by colour on black
        "evaluate": {"n_candidates": 2}})
    extra, _ = write_real_imagery(cfg, tmp_path / "bb", tmp_path / "avd", tmp_path / "truth.json", SkipPolicy(True))
    truth = json.loads((tmp_path / "truth.json").read_text())
    ours = AVDScan(tmp_path / "avd", "Home_005_1")
    real_aspects, measured = [], 0
    fits = {f["image"]: f for r in truth["scans"]["Home_005_1"]["instances"].values() for f in r["frame_fit"]}
    for name, img in sorted(ours.images.items()):
        if len(img.boxes) != 1:                # one object per frame: nothing else to segment
            continue
        b = img.boxes[0]
        k = int(ours.instance_names[b.instance_id][-3:])
        rx0, ry0, rx1, ry1 = fits[name]["real_box"]
        real_aspects.append((rx1 - rx0) / (ry1 - ry0))
        if min(b.x1 - b.x0, b.y1 - b.y0) < 100:   # +-1 px of edge is 1 %: measurable to 2 %
            continue
        frame = ours.read_image(name)
        w, h = shapes[k]
        assert _aspect_read_back(frame, (b.x0, b.y0, b.x1, b.y1)) == pytest.approx(w / h, rel=0.02), name
        measured += 1
    assert measured >= 5, measured
    assert max(real_aspects) / min(real_aspects) > 3        # the real boxes' shapes really vary
    bf = truth["box_fit"]
    assert bf == extra["box_fit"] and bf["frames"] == sum(len(r["frame_fit"]) for r in
                                                          truth["scans"]["Home_005_1"]["instances"].values())
    assert 0 < bf["fill"]["min"] <= bf["fill"]["median"] <= bf["fill"]["max"] <= 1
