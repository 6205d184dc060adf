"""Capture nuisance of the BigBIRD rig: what makes two turntable views differ besides the angle.

Real BigBIRD images come from a Carmine's cheap CMOS sensor (shot + read noise), with small
exposure and white-balance drift between views, an object put down a few millimetres off the
turntable axis (it orbits as the table turns) and rocking a little on the moving table, masks
whose boundary is off by a pixel or two, and JPEG compression. Each effect is one knob of
``data.synthetic`` (``bigbird_*``; 0 switches it off) and draws its randomness from (seed, object,
camera, angle), so files do not depend on the rendering order or process.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from loaders.synthetic.objects import rot_z
from pipeline.infra import seeds


@dataclass(frozen=True)
class RigNuisance:
    read_noise: float = 0.0       # grey levels, std
    shot_noise: float = 0.0       # variance per grey level
    exposure: float = 0.0         # per-view gain std (log scale)
    white_balance: float = 0.0    # per-view, per-channel gain std (log scale)
    decentre_m: float = 0.0       # object offset from the turntable axis
    wobble_deg: float = 0.0       # per-angle yaw wobble std
    wobble_m: float = 0.0         # per-angle position wobble std
    mask_error_px: int = 0        # mask boundary moved by up to this
    quality: int = 92             # JPEG quality

    @classmethod
    def from_config(cls, syn) -> "RigNuisance":
        """From the ``data.synthetic`` config section."""
        return cls(float(syn.bigbird_read_noise), float(syn.bigbird_shot_noise),
                   float(syn.bigbird_exposure_jitter), float(syn.bigbird_wb_jitter),
                   float(syn.bigbird_decentre_mm) / 1000.0, float(syn.bigbird_wobble_deg),
                   float(syn.bigbird_wobble_mm) / 1000.0, int(syn.bigbird_mask_error_px),
                   int(syn.bigbird_jpeg_quality))


def object_pose(nz: RigNuisance, seed: int, name: str, angle: int) -> tuple[np.ndarray, np.ndarray]:
    """(R, t): the object's placement in the table frame at a turntable angle. The decentring is
    one offset per object; the wobble is per angle (all cameras shoot the same placement)."""
    r = seeds.stream(seed, "bigbird-decentre", name)
    phi = r.uniform(0, 2 * np.pi)
    off = nz.decentre_m * np.array([np.cos(phi), np.sin(phi), 0.0])
    w = seeds.stream(seed, "bigbird-wobble", name, angle)
    yaw = w.normal(0.0, nz.wobble_deg) if nz.wobble_deg > 0 else 0.0
    dxy = w.normal(0.0, nz.wobble_m, 2) if nz.wobble_m > 0 else np.zeros(2)
    return rot_z(yaw), off + np.array([dxy[0], dxy[1], 0.0])


SENSOR_ROWS = 32   # rows per band of the sensor noise (about 0.5 MB of float32 temporaries)


@lru_cache(maxsize=2)
def _normal_bank(seed: int, size: int) -> np.ndarray:
    """Standard normals drawn once per process; each image takes a slice at a random offset
    (fresh normals per 1280x1024 image would cost more than rendering it)."""
    bank = seeds.stream(seed, "bigbird-noise-bank").standard_normal(2 * size, dtype=np.float32)
    bank.setflags(write=False)
    return bank


def sensor(rgb: np.ndarray, nz: RigNuisance, seed: int, rng: np.random.Generator) -> np.ndarray:
    """Exposure and white-balance gain, then signal-dependent noise of std sqrt(read^2 + shot * I).
    Both go through 256-entry tables per channel (the image is 8-bit), which keeps a 1280x1024
    view at a few milliseconds."""
    gain = np.exp(rng.normal(0.0, nz.exposure) + rng.normal(0.0, nz.white_balance, 3)) \
        if (nz.exposure > 0 or nz.white_balance > 0) else np.ones(3)
    levels = np.arange(256, dtype=np.float32)
    lut = np.clip(levels[:, None] * gain[None, :].astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
    img = cv2.LUT(rgb, lut.reshape(256, 1, 3))
    if nz.read_noise <= 0 and nz.shot_noise <= 0:
        return img
    sd_lut = np.sqrt(nz.read_noise ** 2 + nz.shot_noise * levels).astype(np.float32)
    n = img.size
    off = int(rng.integers(0, n))
    bank = _normal_bank(seed, n)[off:off + n].reshape(img.shape)
    # The noise in bands of rows: the float32 temporaries of a band stay in the cache (a whole
    # view's are 16 MB each); every pixel's arithmetic is the one of the whole-image calls.
    for r0 in range(0, img.shape[0], SENSOR_ROWS):
        band = img[r0:r0 + SENSOR_ROWS]
        noise = cv2.multiply(bank[r0:r0 + SENSOR_ROWS], cv2.LUT(band, sd_lut))
        cv2.add(band, noise, dst=band, dtype=cv2.CV_8U)
    return img


def bounding_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, w, h) of a boolean mask's true pixels (OpenCV: far cheaper than np.nonzero)."""
    return cv2.boundingRect(mask.view(np.uint8))


def mask_errors(mask: np.ndarray, px: int, rng: np.random.Generator) -> np.ndarray:
    """The boundary moved in or out by 0..px pixels, then a third of the pixels on the new
    boundary flipped (a ragged edge), working on the object's neighbourhood only."""
    if px <= 0 or not mask.any():
        return mask
    bx, by, bw, bh = bounding_box(mask)
    h, w = mask.shape
    pad = px + 2
    y0, y1 = max(0, by - pad), min(h, by + bh + pad)
    x0, x1 = max(0, bx - pad), min(w, bx + bw + pad)
    sub = mask[y0:y1, x0:x1].astype(np.uint8)
    e = int(rng.integers(-px, px + 1))
    if e:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * abs(e) + 1, 2 * abs(e) + 1))
        sub = cv2.dilate(sub, k) if e > 0 else cv2.erode(sub, k)
    edge = cv2.morphologyEx(sub, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)).astype(bool)
    flip = edge & (rng.random(sub.shape) < 1 / 3)
    sub = np.where(flip, 1 - sub, sub).astype(bool)
    out = mask.copy()
    out[y0:y1, x0:x1] = sub
    if not out.any():  # a tiny object eroded away: keep the true mask
        return mask
    return out
