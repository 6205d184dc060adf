"""The object of a category frame, cut out by its map, over black or over real clutter (pure
functions but ``read_backgrounds``).

A test photograph is resampled as COIL views are (``frames.resampled_view``: its object box
becomes the real AVD box, half a box of surround on each side) and so is its segmentation map; the
map is the alpha that blends the object over the background of that patch. The background is black
(the COIL frames' look), or, with ``background = "avd_frames"``, a region of a real AVD frame
resampled to the patch: a seeded frame, a seeded region with the patch's aspect ratio whose height
is 30-100 % of the largest that fits, below the frames' burned-in step label (the top
``LABEL_ROWS`` rows are never used). The photograph's own blue cloth never reaches a frame.

The training views get the same kind of background by default (``training_view``: cut out by the
map onto black, or onto a seeded clutter region the size of the photograph), so the two sides
differ in the object's view, not in what surrounds it; ``data.real_imagery.train_background``
names a deliberate mismatch ('original' keeps the blue cloth).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from loaders.errors import BadInputError
from loaders.files import read_checked
from loaders.image_gate import decode_image
from loaders.real_imagery.frames import apply_sensor, mask_bbox, paste, paste_cutout, resampled_view

LABEL_ROWS = 24            # the "Step #N" label of the avd_frames copy: about 50 x 20 px, top left
MIN_REGION_FRACTION = 0.3  # smallest region height, as a fraction of the largest that fits


def read_backgrounds(folder: Path, skips) -> list[np.ndarray]:
    """Every readable RGB frame (*.png, *.jpg) of ``folder``, sorted by name; bad files follow the
    skip policy (``skips.handle``); no readable frame is an error naming the folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInputError(folder, "'data.avd_frames_root' is not an existing folder")
    out = []
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() not in (".png", ".jpg", ".jpeg"):
            continue
        try:
            data = read_checked(p, folder, "background frame")
            bgr = decode_image(data, p, cv2.IMREAD_COLOR, expect=("PNG", "JPEG"))
            if bgr.shape[0] <= LABEL_ROWS + 8 or bgr.shape[1] < 8:
                raise BadInputError(p, f"background frame is {bgr.shape[1]}x{bgr.shape[0]}, too small")
            out.append(np.ascontiguousarray(bgr[:, :, ::-1]))
        except BadInputError as err:
            skips.handle(err, "avd_frames", "background frame")
    if not out:
        raise BadInputError(folder, "holds no readable background frame (*.png, *.jpg)")
    return out


def clutter_patch(backgrounds: list[np.ndarray], shape, rng: np.random.Generator) -> np.ndarray:
    """A (H, W, 3) uint8 region of a seeded background frame, resampled to ``shape``."""
    H, W = int(shape[0]), int(shape[1])
    frame = backgrounds[int(rng.integers(len(backgrounds)))][LABEL_ROWS:]
    fh, fw = frame.shape[:2]
    aspect = W / H
    h_max = min(fh, fw / aspect)
    h = max(rng.uniform(MIN_REGION_FRACTION, 1.0) * h_max, 1.0)
    w = max(min(h * aspect, fw), 1.0)
    y0 = int(rng.uniform(0.0, fh - h + 1e-9))
    x0 = int(rng.uniform(0.0, fw - w + 1e-9))
    region = frame[y0:y0 + max(int(round(h)), 1), x0:x0 + max(int(round(w)), 1)]
    shrink = region.shape[0] * region.shape[1] > H * W
    return cv2.resize(region, (W, H), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def training_view(rgb: np.ndarray, alpha: np.ndarray, kind: str, backgrounds, rng: np.random.Generator) -> np.ndarray:
    """A training photograph on background ``kind``: 'original' (as it is), 'black' (cut out by its
    map) or 'avd_frames' (cut out over a clutter region the photograph's size, drawn by ``rng``)."""
    if kind == "original":
        return rgb
    a = np.clip(alpha, 0.0, 1.0).astype(np.float32)[:, :, None]
    bg = (np.zeros_like(rgb) if kind == "black" else clutter_patch(backgrounds, rgb.shape[:2], rng)).astype(np.float32)
    return np.clip(np.round(a * rgb.astype(np.float32) + (1.0 - a) * bg), 0, 255).astype(np.uint8)


def cutout_patch(rgb: np.ndarray, mask: np.ndarray, alpha: np.ndarray, box_w: int, box_h: int,
                 background: np.ndarray | None):
    """The photograph resampled to the box, blended by its map over ``background`` (a patch of the
    same size, or None = black): (patch uint8, (dx, dy) of the object box inside it)."""
    patch, off = resampled_view(rgb, mask, box_w, box_h)
    a, _ = resampled_view(np.round(np.clip(alpha, 0.0, 1.0) * 255).astype(np.uint8), mask, box_w, box_h)
    a = (a.astype(np.float32) / 255.0)[:, :, None]
    bg = np.zeros_like(patch) if background is None else background
    if bg.shape != patch.shape:
        raise ValueError(f"background patch {bg.shape} does not match the object patch {patch.shape}")
    out = a * patch.astype(np.float32) + (1.0 - a) * bg.astype(np.float32)
    return np.clip(np.round(out), 0, 255).astype(np.uint8), off


def patch_shape(mask: np.ndarray, box_w: int, box_h: int) -> tuple[int, int]:
    """(H, W) of the patch ``resampled_view`` makes for this mask and box (the background's size)."""
    return patch_geometry(mask, box_w, box_h)[0]


def patch_geometry(mask: np.ndarray, box_w: int, box_h: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """((H, W), (dx, dy)) of the patch ``resampled_view`` makes for this mask and box."""
    probe, off = resampled_view(mask.astype(np.uint8), mask, box_w, box_h)
    return probe.shape[:2], off


def render_category_frame(size: tuple[int, int], items, backgrounds, noise_std: float, blur_sigma_px: float,
                          rng: np.random.Generator, bg_rngs) -> np.ndarray:
    """A (H, W, 3) frame of ``size`` = (W, H): over black (``backgrounds`` None), or first, under
    every object, a clutter region around each (drawn with the item's own generator of
    ``bg_rngs``, same order as ``items``) as large as its patch; then each (rgb, mask, alpha, box)
    cut out by its alpha (``frames.paste_cutout``) in the given order (the farthest first: a nearer
    object covers a farther one only with its own silhouette, where their real boxes overlap; no
    object is cut by another's background); then the sensor model on each box."""
    frame = np.zeros((size[1], size[0], 3), np.uint8)
    if backgrounds is not None:
        for (_, mask, _, box), g in zip(items, bg_rngs):
            shape, off = patch_geometry(mask, int(box[2]) - int(box[0]), int(box[3]) - int(box[1]))
            paste(frame, clutter_patch(backgrounds, shape, g), off, box)
    for rgb, mask, alpha, box in items:
        paste_cutout(frame, rgb, mask, alpha, box)
    for *_, box in items:
        apply_sensor(frame, box, noise_std, blur_sigma_px, rng)
    return frame


def crop_overrun(mask: np.ndarray, margin: float, square: bool) -> int:
    """Pixels by which the features stage's crop of this photograph can run off it on its worst
    side (0: inside): its mask box grown by ``margin`` times the longer side on every side and,
    if ``square``, to a square about the box centre (``pipeline.scoring.crops.crop_box``), plus a
    pixel for that function's rounding, so the bound holds whichever way it rounds."""
    x0, y0, x1, y1 = mask_bbox(mask)
    H, W = mask.shape[:2]
    long_side = max(x1 - x0, y1 - y0)
    if square:
        half = long_side * (0.5 + margin) + 1.0
        cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        reach = (half - cx, half - cy, cx + half - W, cy + half - H)
    else:
        m = margin * long_side + 1.0
        reach = (m - x0, m - y0, x1 + m - W, y1 + m - H)
    return max(0, int(np.ceil(max(reach))))


def on_surround(views: dict, kind: str, backgrounds, rng_of, crop=None) -> tuple[dict, int]:
    """A side's training photographs {angle: (rgb, mask, alpha)} on the frames' surround: each
    cut out by its alpha onto ``kind`` ('black', 'avd_frames': ``training_view`` with the
    generator ``rng_of(angle)``; 'original' leaves it as it is). ``crop`` = (margin, square): first
    every view is extended by the same border (so the side keeps one image size and one rig),
    wide enough that no crop the features stage takes runs off its photograph, and the border
    gets the surround too: no pad value reaches a training crop. Returns (views, border px)."""
    border = 0
    if crop is not None and kind != "original":
        border = max(crop_overrun(m, *crop) for _, m, _ in views.values())
    out = {}
    for a, (rgb, mask, alpha) in views.items():
        if border:
            rgb = cv2.copyMakeBorder(rgb, border, border, border, border, cv2.BORDER_CONSTANT, value=0)
            mask = np.pad(mask, border)
            alpha = np.pad(np.asarray(alpha, np.float32), border)
        out[a] = (training_view(rgb, alpha, kind, backgrounds, rng_of(a)), mask, alpha)
    return out, border
