"""Procedural texture families: the synthetic *source-domain* categories.

The classifier stage trains AlexNet to tell these categories apart (the way ImageNet categories
differ from BigBIRD instances); the synthetic instances' faces are painted with them, so an
instance's score vector changes with which faces the camera sees.

``texture(category, rng, size)`` returns an RGB uint8 image; every call draws fresh parameters
(frequency, orientation, phase, colours) within the family, so a category is a distribution.
"""
from __future__ import annotations

import numpy as np

CATEGORY_NAMES = (
    "stripes", "checker", "dots", "rings", "chevron", "plaid",
    "blobs", "sunburst", "honeycomb", "crosshatch", "waves", "barcode",
)
N_CATEGORIES = len(CATEGORY_NAMES)

# Each family has a characteristic pair of hues (degrees); colours are jittered around them.
_HUES = (
    (0, 210), (45, 270), (120, 330), (200, 30), (280, 90), (160, 10),
    (90, 240), (30, 180), (330, 140), (250, 60), (180, 300), (15, 120),
)


def hsv_to_rgb(h: float, s: float, v: float) -> np.ndarray:
    h = (h % 360) / 60.0
    c = v * s
    x = c * (1 - abs(h % 2 - 1))
    m = v - c
    r, g, b = [(c, x, 0), (x, c, 0), (0, c, x), (0, x, c), (x, 0, c), (c, 0, x)][int(h) % 6]
    return np.array([r + m, g + m, b + m], dtype=np.float32)


def palette(category: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    h1, h2 = _HUES[category % len(_HUES)]
    c1 = hsv_to_rgb(h1 + rng.uniform(-15, 15), rng.uniform(0.55, 0.95), rng.uniform(0.55, 0.95))
    c2 = hsv_to_rgb(h2 + rng.uniform(-15, 15), rng.uniform(0.35, 0.8), rng.uniform(0.2, 0.6))
    return c1, c2


def _grid(size: tuple[int, int], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    h, w = size
    s = max(h, w)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    return (x - w / 2) / s, (y - h / 2) / s


def _rot(x: np.ndarray, y: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(a), np.sin(a)
    return c * x - s * y, s * x + c * y


def _pattern(category: int, rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """Scalar field in [0, 1] that defines the family."""
    x, y = _grid(size, rng)
    a = rng.uniform(0, np.pi)
    f = rng.uniform(4, 9)          # cycles across the image
    ph = rng.uniform(0, 2 * np.pi)
    name = CATEGORY_NAMES[category % N_CATEGORIES]
    if name == "stripes":
        u, _ = _rot(x, y, a)
        return (np.sin(2 * np.pi * f * u + ph) > 0).astype(np.float32)
    if name == "checker":
        u, v = _rot(x, y, a)
        return ((np.floor(f * u + ph) + np.floor(f * v)) % 2).astype(np.float32)
    if name == "dots":
        u, v = _rot(x, y, a)
        fu, fv = (f * u) % 1 - 0.5, (f * v) % 1 - 0.5
        return (fu ** 2 + fv ** 2 < rng.uniform(0.06, 0.14)).astype(np.float32)
    if name == "rings":
        cx, cy = rng.uniform(-0.3, 0.3, 2)
        r = np.hypot(x - cx, y - cy)
        return (np.sin(2 * np.pi * f * r + ph) > 0).astype(np.float32)
    if name == "chevron":
        u, v = _rot(x, y, a)
        return (np.sin(2 * np.pi * f * (u + np.abs((v * f) % 1 - 0.5) / f * 2)) > 0).astype(np.float32)
    if name == "plaid":
        u, v = _rot(x, y, a)
        band = lambda t: (np.sin(2 * np.pi * f * t + ph) > 0.6).astype(np.float32)
        return np.clip(0.6 * band(u) + 0.6 * band(v), 0, 1)
    if name == "blobs":
        k = 12
        g = rng.normal(size=(k, k)).astype(np.float32)
        import cv2
        big = cv2.resize(g, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)
        return (big > 0).astype(np.float32)
    if name == "sunburst":
        cx, cy = rng.uniform(-0.2, 0.2, 2)
        th = np.arctan2(y - cy, x - cx)
        n = rng.integers(8, 16)
        return (np.sin(n * th + ph) > 0).astype(np.float32)
    if name == "honeycomb":
        u, v = _rot(x, y, a)
        s3 = np.sqrt(3)
        q = (2 / 3 * u) * f
        r = (-1 / 3 * u + s3 / 3 * v) * f
        # distance to hex centre via cube rounding -> edges where the fraction is near .5
        fx, fz = q - np.round(q), r - np.round(r)
        edge = np.maximum(np.abs(fx), np.maximum(np.abs(fz), np.abs(fx + fz)))
        return (edge > 0.35).astype(np.float32)
    if name == "crosshatch":
        u, v = _rot(x, y, a)
        l1 = np.abs(np.sin(np.pi * f * (u + v))) < 0.25
        l2 = np.abs(np.sin(np.pi * f * (u - v))) < 0.25
        return (l1 | l2).astype(np.float32)
    if name == "waves":
        u, v = _rot(x, y, a)
        return (np.sin(2 * np.pi * f * u + 1.5 * np.sin(2 * np.pi * f * 0.5 * v) + ph) > 0).astype(np.float32)
    if name == "barcode":
        u, _ = _rot(x, y, rng.uniform(-0.15, 0.15))
        n = 48
        bars = rng.random(n) < 0.5
        idx = np.clip(((u + 0.5) * n).astype(int), 0, n - 1)
        return bars[idx].astype(np.float32)
    raise ValueError(f"unknown texture category {category}")  # pragma: no cover


def texture(category: int, rng: np.random.Generator, size: tuple[int, int] = (128, 128)) -> np.ndarray:
    """An RGB uint8 texture of the given family; fresh parameters on every call."""
    if not 0 <= category < N_CATEGORIES:
        raise ValueError(f"texture category {category} out of range 0..{N_CATEGORIES - 1}")
    m = _pattern(category, rng, size)[..., None]
    c1, c2 = palette(category, rng)
    img = m * c1 + (1 - m) * c2
    img += rng.normal(0, 0.03, size=img.shape).astype(np.float32)  # paper/print grain
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)
