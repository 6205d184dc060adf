"""Crops and pastes that match, read back from written files (real COIL-100 views on a real AVD
scan): every training crop lies inside its photograph (no pad value reaches it) and its surround
is the frames' (black, or real clutter); every framed object shows its own photograph wherever no
other object's silhouette lies on it (no object is cut by another's paste or ground), and the
surround of every framed crop is the frames' kind too."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tests.loaders.realdata import need

OBJECTS = [2, 3, 5, 8, 13]
LUMA = np.array([0.299, 0.587, 0.114])


@pytest.fixture(scope="module", params=["black", "avd_frames"])
def written(request, tmp_path_factory):
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.config import load_config
    from tests.conftest import ROOT

    coil, avd, frames = need("coil100"), need("avd"), need("avd_frames")
    out = tmp_path_factory.mktemp(f"rb_{request.param}")
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(out / "artifacts")},
        "data": {"coil_root": str(coil), "avd_root": str(avd), "avd_frames_root": str(frames),
                 "scans": ["Home_005_1"],
                 "real_imagery": {"objects": OBJECTS, "background": request.param, "noise_std": 0.0,
                                  "blur_sigma_px": 0.0, "jpeg_quality": 100}},
        "evaluate": {"n_candidates": 2}})
    write_real_imagery(cfg, out / "bigbird", out / "avd", out / "truth.json", SkipPolicy(True))
    return cfg, out, coil, request.param


def _surround_is(kind: str, px: np.ndarray, where: str) -> None:
    """Pixels (N, 3) of a crop's surround are the frames' kind: black, or a real room (not all
    black, even where dark, and not one constant pad value: a plain wall varies by a few levels)."""
    black = np.percentile(px.max(axis=1), 99) <= 12
    if kind == "black":
        assert black, where
    else:
        assert not black and px.std(axis=0).max() > 1.5, where


def _read(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1]


def test_training_crops_stay_on_their_photograph(written):
    from loaders.pbm import read_pbm
    from loaders.real_imagery.frames import mask_bbox
    from pipeline.scoring.crops import CropPolicy

    cfg, out, _, kind = written
    policy = CropPolicy.from_config(cfg)
    n = 0
    for jpg in sorted((out / "bigbird").glob("coil_obj*/NP1_*.jpg")):
        rgb = _read(jpg)
        mask = read_pbm(jpg.parent / "masks" / f"{jpg.stem}_mask.pbm")
        x0, y0, x1, y1 = policy.crop_box(mask_bbox(mask))
        H, W = mask.shape
        assert x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H, f"{jpg}: crop {(x0, y0, x1, y1)} leaves {W}x{H}"
        near = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        crop_px = rgb[y0:y1, x0:x1][~near[y0:y1, x0:x1]]
        _surround_is(kind, crop_px, str(jpg))
        n += 1
    assert n == len(OBJECTS) * 36


def test_no_framed_object_is_cut_by_another_paste(written):
    from loaders.avd import AVDScan
    from loaders.coil import CoilFolder, object_name
    from loaders.real_imagery.frames import alpha_of, resampled_view
    from pipeline.scoring.crops import CropPolicy

    cfg, out, coil_root, kind = written
    truth = json.loads((out / "truth.json").read_text())["scans"]["Home_005_1"]["instances"]
    views = {rec["coil_object"]: {f["image"]: f["view"] for f in rec["frame_fit"]} for rec in truth.values()}
    coil = CoilFolder(coil_root)
    scan = AVDScan(out / "avd", "Home_005_1")
    policy = CropPolicy.from_config(cfg)
    checked = shared = 0
    for name, img in sorted(scan.images.items()):
        if not img.boxes:
            continue
        frame = _read(img.path)
        H, W = frame.shape[:2]
        placed = []     # (box, object pixels here, expected rgb) of every object in the frame
        for b in img.boxes:
            k = int(scan.instance_names[b.instance_id].removeprefix("coil_obj"))
            rgb, mask = coil.read(coil.view(k, views[k][name]))
            bw, bh = b.x1 - b.x0, b.y1 - b.y0
            patch, (dx, dy) = resampled_view(rgb, mask, bw, bh)
            a, _ = resampled_view(alpha_of(mask), mask, bw, bh)
            full_a = np.zeros((H, W), np.uint8)
            full_rgb = np.zeros((H, W, 3), np.uint8)
            px, py = b.x0 - dx, b.y0 - dy
            fy0, fx0 = max(py, 0), max(px, 0)
            fy1, fx1 = min(py + a.shape[0], H), min(px + a.shape[1], W)
            full_a[fy0:fy1, fx0:fx1] = a[fy0 - py:fy1 - py, fx0 - px:fx1 - px]
            full_rgb[fy0:fy1, fx0:fx1] = patch[fy0 - py:fy1 - py, fx0 - px:fx1 - px]
            placed.append(((b.x0, b.y0, b.x1, b.y1), full_a, full_rgb, object_name(k)))
        for i, (box, a, rgb, obj) in enumerate(placed):
            others = np.zeros_like(a)
            for j, (_, a2, _, _) in enumerate(placed):
                if j != i:
                    others |= cv2.dilate((a2 > 0).astype(np.uint8), np.ones((5, 5), np.uint8))
            shared += int(others.any() and (others & (a > 0)).any())
            inner = (cv2.erode((a == 255).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & (others == 0)
            if inner.sum() < 50:            # too small to read back (or wholly behind a nearer object)
                continue
            grey = (frame.astype(float) @ LUMA)[inner] - (rgb.astype(float) @ LUMA)[inner]
            # own pixels: resampling and the JPEG's chroma subsampling move them a few grey levels
            # (more at sharp texture); another object's ground, square or clutter pasted over them
            # moves a whole region by tens of levels
            far = float(np.mean(np.abs(grey) > 40))
            assert far <= 0.03, f"{name} {obj}: {far:.1%} of its pixels are not its photograph's"
            cx0, cy0, cx1, cy1 = policy.crop_box(box)
            cx0, cy0, cx1, cy1 = max(cx0, 0), max(cy0, 0), min(cx1, W), min(cy1, H)
            anyobj = np.zeros((H, W), bool)
            for _, a2, _, _ in placed:
                anyobj |= cv2.dilate((a2 > 0).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
            sur = ~anyobj[cy0:cy1, cx0:cx1]
            if sur.sum() >= 50:
                _surround_is(kind, frame[cy0:cy1, cx0:cx1][sur], f"{name} {obj} surround")
            checked += 1
    assert checked >= 20, checked
