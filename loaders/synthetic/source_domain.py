"""The synthetic *source domain*: labelled training crops of the procedural texture families.

The synthetic classifier learns these categories the way an ImageNet AlexNet learns ImageNet
categories; the object instances (BigBIRD/AVD stand-ins) are a different domain whose faces are
painted with the same families, so an instance's score vector depends on which faces are seen.

Each image imitates a detector crop: a shape (polygon, ellipse, box-like prism in perspective or a
cylinder) filled with the category's texture on a random background (flat colour, gradient, smooth
noise, or low-contrast clutter from *other* families), then random lighting, blur, sensor noise and
JPEG re-encoding. Images are generated on the fly from ``(seed, stream, index)`` so any subset is
reproducible without storing a data set, and a train and a validation stream never share a draw.
"""
from __future__ import annotations

import cv2
import numpy as np

from pipeline.infra import seeds
from loaders.synthetic.textures import CATEGORY_NAMES, N_CATEGORIES, texture
from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.workers import worker_pool

TRAIN_STREAM = 0
VAL_STREAM = 1

LABEL_ORDER = 2**31 - 1  # the labels' order: a name past every image index
SHAPES = ("polygon", "ellipse", "prism", "cylinder")


def _rng(seed: int, stream: int, index: int) -> np.random.Generator:
    # One generator per image: an image does not depend on which others are drawn, or in what order.
    return seeds.stream(int(seed), int(stream), int(index))


def labels_for(n: int, categories: int, seed: int, stream: int) -> np.ndarray:
    """Balanced labels (each category n/categories times, +-1), in a seeded random order."""
    lab = np.arange(n) % categories
    seeds.stream(int(seed), int(stream), LABEL_ORDER).shuffle(lab)
    return lab.astype(np.int64)


# -- backgrounds ---------------------------------------------------------------------------------
def _background(rng: np.random.Generator, size: int, category: int, categories: int) -> np.ndarray:
    kind = rng.choice(("flat", "gradient", "noise", "clutter"), p=(0.2, 0.25, 0.2, 0.35))
    base = rng.uniform(0.05, 0.95, 3).astype(np.float32)
    if kind == "flat":
        img = np.broadcast_to(base, (size, size, 3)).copy()
    elif kind == "gradient":
        other = rng.uniform(0.05, 0.95, 3).astype(np.float32)
        a = rng.uniform(0, 2 * np.pi)
        x = np.arange(size, dtype=np.float32) / size - 0.5
        t = np.clip(np.cos(a) * x[None, :] + np.sin(a) * x[:, None] + 0.5, 0, 1)[..., None]
        img = base * (1 - t) + other * t
    elif kind == "noise":
        k = int(rng.integers(3, 10))
        low = rng.uniform(0, 1, (k, k, 3)).astype(np.float32)
        img = cv2.resize(low, (size, size), interpolation=cv2.INTER_CUBIC)
        img = base * 0.5 + 0.5 * np.clip(img, 0, 1)
    else:
        # Low-contrast clutter from a *different* family, so it never carries the label.
        others = [c for c in range(categories) if c != category]
        clut = texture(int(rng.choice(others)), rng, (size, size)).astype(np.float32) / 255.0
        alpha = rng.uniform(0.15, 0.45)
        img = base * (1 - alpha) + clut * alpha
    img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(rng.uniform(0.0, 0.04))
    return img.astype(np.float32)


# -- shapes --------------------------------------------------------------------------------------
def _tex(category: int, rng: np.random.Generator, side: int) -> np.ndarray:
    return texture(category, rng, (side, side)).astype(np.float32) / 255.0


def _paste_quad(canvas: np.ndarray, tex: np.ndarray, quad: np.ndarray, shade: float) -> None:
    """Warp a square texture onto a convex quad of the canvas (perspective), shaded."""
    h, w = tex.shape[:2]
    src = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float32)
    M = cv2.getPerspectiveTransform(src, quad.astype(np.float32))
    size = canvas.shape[0]
    warped = cv2.warpPerspective(tex * shade, M, (size, size), flags=cv2.INTER_LINEAR)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillConvexPoly(mask, np.round(quad * 16).astype(np.int32), 1, lineType=cv2.LINE_AA, shift=4)
    m = mask.astype(bool)
    canvas[m] = warped[m]


def _fill(canvas: np.ndarray, tex: np.ndarray, mask: np.ndarray) -> None:
    m = mask.astype(bool)
    canvas[m] = tex[m]


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    yaw = rng.uniform(0, 2 * np.pi)
    pitch = rng.uniform(np.deg2rad(-35), np.deg2rad(35))
    roll = rng.uniform(np.deg2rad(-15), np.deg2rad(15))
    cz, sz = np.cos(yaw), np.sin(yaw)
    cx, sx = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(roll), np.sin(roll)
    Rz = np.array([[cz, 0, sz], [0, 1, 0], [-sz, 0, cz]])   # about the vertical (image y) axis
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Rr = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rr @ Rx @ Rz


def _draw_prism(canvas, rng, category, centre, extent) -> None:
    """A box (cereal box, carton) in perspective; each visible face its own texture and shade."""
    dims = rng.uniform(0.35, 1.0, 3)
    dims /= dims.max()
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * dims / 2
    R = _random_rotation(rng)
    pts = corners @ R.T
    dist = rng.uniform(2.0, 4.0)                     # camera distance in box units: perspective strength
    z = pts[:, 2] + dist
    proj = pts[:, :2] / z[:, None] * dist
    span = (proj.max(0) - proj.min(0)).max()
    img_pts = (proj - (proj.max(0) + proj.min(0)) / 2) / span * extent + centre
    faces = ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3))
    light = rng.normal(size=3)
    light /= np.linalg.norm(light)
    cam = np.array([0.0, 0.0, -dist])
    drawn = []
    for f in faces:
        P = pts[list(f)]
        n = np.cross(P[1] - P[0], P[3] - P[0])
        n /= np.linalg.norm(n) + 1e-12
        centroid = P.mean(0)
        if np.dot(n, centroid) < 0:                  # make the normal point outwards
            n = -n
        if np.dot(n, cam - centroid) <= 0:           # back face
            continue
        drawn.append((centroid[2], f, n))
    for _, f, n in sorted(drawn, key=lambda t: -t[0]):  # far to near
        shade = 0.65 + 0.4 * max(0.0, float(np.dot(n, -light))) + rng.uniform(-0.05, 0.05)
        side = int(rng.integers(48, 112))
        _paste_quad(canvas, _tex(category, rng, side), img_pts[list(f)], shade)


def _draw_cylinder(canvas, rng, category, centre, extent) -> None:
    """A bottle/can: texture wrapped around a vertical cylinder (compressed towards the rims)."""
    size = canvas.shape[0]
    h = extent
    w = extent * rng.uniform(0.35, 0.8)
    x0, y0 = centre[0] - w / 2, centre[1] - h / 2
    tw, th = max(8, int(round(w))), max(8, int(round(h)))
    tex = _tex(category, rng, max(tw, th) + 8)
    # Orthographic wrap: column u in [-1, 1] sees the surface at angle asin(u).
    u = np.linspace(-0.999, 0.999, tw, dtype=np.float32)
    phase = rng.uniform(0, 0.5)
    src_x = ((np.arcsin(u) / np.pi + 0.5) * 0.5 + phase) * (tex.shape[1] - 1)
    map_x = np.broadcast_to(src_x, (th, tw)).astype(np.float32)
    map_y = np.broadcast_to(np.linspace(0, tex.shape[0] - 1, th, dtype=np.float32)[:, None], (th, tw)).copy()
    body = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR)
    shade = (0.45 + 0.55 * np.sqrt(1 - u ** 2)) * rng.uniform(0.8, 1.15)
    body = body * shade[None, :, None]
    # Rotate the whole cylinder a little (not always upright in a crop).
    M = cv2.getRotationMatrix2D((tw / 2, th / 2), rng.uniform(-20, 20), 1.0)
    M[:, 2] += (x0, y0)
    warped = cv2.warpAffine(body, M, (size, size), flags=cv2.INTER_LINEAR)
    mask = cv2.warpAffine(np.ones((th, tw), np.float32), M, (size, size), flags=cv2.INTER_NEAREST)
    _fill(canvas, warped, mask > 0.5)


def _draw_polygon(canvas, rng, category, centre, extent) -> None:
    size = canvas.shape[0]
    n = int(rng.integers(3, 9))
    # Evenly spread vertex angles with jitter: no slivers.
    ang = rng.uniform(0, 2 * np.pi) + (np.arange(n) + rng.uniform(-0.3, 0.3, n)) * (2 * np.pi / n)
    rad = rng.uniform(0.6, 1.0, n) * extent / 2
    pts = np.stack([centre[0] + rad * np.cos(ang), centre[1] + rad * np.sin(ang)], 1)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_AA, shift=4)
    _fill(canvas, _warped_texture(rng, category, size), mask)


def _draw_ellipse(canvas, rng, category, centre, extent) -> None:
    size = canvas.shape[0]
    axes = (extent / 2, extent / 2 * rng.uniform(0.4, 1.0))
    mask = np.zeros((size, size), np.uint8)
    cv2.ellipse(mask, ((float(centre[0]), float(centre[1])), (2 * axes[0], 2 * axes[1]), rng.uniform(0, 180)), 1, -1)
    _fill(canvas, _warped_texture(rng, category, size), mask)


def _warped_texture(rng, category, size) -> np.ndarray:
    """A texture seen obliquely: random perspective warp of a canvas-size texture."""
    tex = _tex(category, rng, int(rng.integers(size // 2, size + 1)))
    th = tex.shape[0]
    src = np.array([[0, 0], [th - 1, 0], [th - 1, th - 1], [0, th - 1]], np.float32)
    dst = src * (size / th) + rng.uniform(-0.15, 0.15, (4, 2)).astype(np.float32) * size
    M = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
    return cv2.warpPerspective(tex, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


_DRAW = {"polygon": _draw_polygon, "ellipse": _draw_ellipse, "prism": _draw_prism, "cylinder": _draw_cylinder}
_SHAPE_P = (0.2, 0.15, 0.4, 0.25)


def render(category: int, rng: np.random.Generator, size: int = 128, categories: int = N_CATEGORIES) -> np.ndarray:
    """One source-domain crop of ``category``: RGB uint8 (size, size, 3)."""
    if not 0 <= category < categories <= N_CATEGORIES:
        raise ValueError(f"category {category} out of range 0..{categories - 1} "
                         f"(at most {N_CATEGORIES} texture families)")
    canvas = _background(rng, size, category, categories)
    shape = SHAPES[int(rng.choice(len(SHAPES), p=_SHAPE_P))]
    # Detector-like framing: the object fills 55-95% of the crop, off centre by up to 12%.
    extent = size * rng.uniform(0.55, 0.95)
    centre = size / 2 + rng.uniform(-0.12, 0.12, 2) * size
    _DRAW[shape](canvas, rng, category, centre, extent)
    # Lighting: global gain, colour tint, a soft illumination gradient.
    gain = rng.uniform(0.7, 1.3)
    tint = rng.uniform(0.85, 1.15, 3).astype(np.float32)
    x = np.arange(size, dtype=np.float32) / size - 0.5
    a = rng.uniform(0, 2 * np.pi)
    k = rng.uniform(0, 0.35)
    ramp = 1 + k * (np.cos(a) * x[None, :] + np.sin(a) * x[:, None])
    img = canvas * (gain * tint)[None, None, :] * ramp[..., None]
    if rng.random() < 0.6:
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 1.3))
    img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(rng.uniform(0, 0.03))
    out = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
    if rng.random() < 0.5:
        # Real JPEG round trip: the instance images are JPEGs too.
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(40, 96))])
        out = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    return out


def render_set(n: int, size: int, categories: int, seed: int, stream: int,
               start: int = 0, progress: bool = False, desc: str = "source images") -> tuple[np.ndarray, np.ndarray]:
    """Images ``start..start+n-1`` of a stream: (uint8 (n, size, size, 3), int64 labels (n,))."""

    labels = labels_for(start + n, categories, seed, stream)[start:]
    images = np.empty((n, size, size, 3), np.uint8)
    for i in progress_bar(range(n), desc=desc, unit="img", enabled=progress, leave=False):
        images[i] = render(int(labels[i]), _rng(seed, stream, start + i), size, categories)
    return images, labels


def category_names(categories: int) -> list[str]:
    if not 2 <= categories <= N_CATEGORIES:
        raise ValueError(f"source-domain categories must be 2..{N_CATEGORIES}, got {categories}")
    return list(CATEGORY_NAMES[:categories])


def _render_chunk(args: tuple) -> tuple[int, np.ndarray]:
    """One worker task of ``render_set_parallel`` (module level so spawned processes import it):
    images ``start..`` of a stream with their labels given (the label order depends on the set's
    size, so workers must not draw it themselves)."""
    labels, size, categories, seed, stream, start = args
    import cv2
    cv2.setNumThreads(1)  # one process per core already
    out = np.empty((len(labels), size, size, 3), np.uint8)
    for i, lab in enumerate(labels):
        out[i] = render(int(lab), _rng(seed, stream, start + i), size, categories)
    return start, out


def render_set_parallel(n: int, size: int, categories: int, seed: int, stream: int, workers: int,
                        chunk: int = 250, progress=None) -> tuple[np.ndarray, np.ndarray]:
    """``render_set`` spread over ``workers`` processes, chunk by chunk. Every image draws from
    its own (seed, stream, index) generator, so the arrays are identical for any worker count.
    ``progress``: an object with ``update(k)`` (e.g. a tqdm bar), called per finished chunk."""
    labels = labels_for(n, categories, seed, stream)
    if workers <= 1 or n <= chunk:
        images = render_set(n, size, categories, seed, stream)[0]
        if progress is not None:
            progress.update(n)
        return images, labels

    images = np.empty((n, size, size, 3), np.uint8)
    tasks = [(labels[s:s + chunk], size, categories, seed, stream, s) for s in range(0, n, chunk)]
    with worker_pool(workers) as pool:
        for start, block in pool.map(_render_chunk, tasks):
            images[start:start + len(block)] = block
            if progress is not None:
                progress.update(len(block))
    return images, labels
