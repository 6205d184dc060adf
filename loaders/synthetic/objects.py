"""Synthetic object instances: convex prisms shaped like the real AVD/BigBIRD objects.

Object frame = BigBIRD table frame: metres, z up, origin at the centre of the base on the
turntable axis. An instance is one or two convex parts (a body prism, optionally a narrower neck
prism on top, like a bottle). Side faces are painted with the source-domain texture families of
``loaders.synthetic.textures`` by *region*: the front (outward normal within 45 deg of +x), the
back (of -x) and the two sides; caps get a plain colour. So which families a camera sees changes
with the direction it looks from, which is what makes a classifier's scores viewpoint-dependent.

A region's texture is generated once, deterministically from (texture key, data seed), and wraps
around the region's faces (each face shows its own slice). Some keys are shared between
instances (same family and the same generated image), so single views alias between classes,
as in the paper. Both writers call ``make_instance`` and get identical appearance.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from loaders.synthetic.textures import CATEGORY_NAMES, N_CATEGORIES, palette, texture
from pipeline.infra.config.inputs import AVD_INSTANCES
from pipeline.infra import seeds
from loaders.synthetic.textures import hsv_to_rgb

# The real AVD instance map (docs/formats/avd_instance_id_map.txt; its names live with the config,
# which checks data.synthetic.instances against them), embedded: readers of a synthetic root find
# it beside the scan, exactly as in a real download.
AVD_INSTANCE_MAP_TEXT = "".join(f"{name} {i}\n" for i, name in enumerate(AVD_INSTANCES))
AVD_INSTANCE_IDS: dict[str, int] = {name: i for i, name in enumerate(AVD_INSTANCES)}

REGIONS = ("front", "left", "back", "right")
PX_PER_M = 1200.0  # texture resolution: ~2 texels per image pixel at BigBIRD distance


# ----------------------------------------------------------------------------------------------
# Shape and paint specifications

@dataclass(frozen=True)
class PartSpec:
    """One convex prism: an n-gon (ellipse-inscribed) or a box, extruded from z0 to z1."""
    kind: str                 # "box" (rx = half depth along x, ry = half width along y) or "ngon"
    rx: float
    ry: float
    z0: float
    z1: float
    n: int = 4                # sides of the n-gon
    painted: bool = True      # side faces carry the region textures (else plain cap colour)


@dataclass(frozen=True)
class InstanceSpec:
    name: str
    parts: tuple[PartSpec, ...]
    # region -> (texture key, family); keys shared between instances share the image.
    paint: dict = field(hash=False, compare=False)
    cap_hue: float = 0.0      # hue of caps/necks (degrees)

    @property
    def height(self) -> float:
        return max(p.z1 for p in self.parts)


def _fam(name: str) -> int:
    return CATEGORY_NAMES.index(name)


def _bottle(r_body: tuple[float, float], h_body: float, r_neck: float, h_neck: float, n: int = 8):
    return (PartSpec("ngon", r_body[0], r_body[1], 0.0, h_body, n),
            PartSpec("ngon", r_neck, r_neck, h_body, h_body + h_neck, 8, painted=False))


def _box(depth: float, width: float, height: float):
    return (PartSpec("box", depth / 2, width / 2, 0.0, height),)


def _paint(front, sides, back, *, shared: dict | None = None, name: str = ""):
    """Region -> (texture key, family). ``shared`` maps a region to a shared texture key."""
    shared = shared or {}
    out = {}
    for region, fam in (("front", front), ("left", sides), ("back", back), ("right", sides)):
        group = "sides" if region in ("left", "right") else region
        key = shared.get(group, f"{name}/{group}")
        out[region] = (key, _fam(fam))
    return out


# Sizes roughly as the real objects (metres); paint = (front, sides, back) families plus shared
# texture keys. Designed aliasing, as in real product shelves:
# - shared faces: the syrup's back label is the cereal boxes' back panel (barcode); cholula and
#   crystal have the same side wrap (dots); tapatio's back is cholula's back (sunburst);
#   listerine's sides are the syrup's sides (waves);
# - near twins: the two honey_bunches boxes differ only on the back (barcode vs blobs).
# So some single views of different classes look alike and only the viewpoint tells them apart.
_KNOWN: dict[str, tuple] = {
    "aunt_jemima_original_syrup": (_bottle((0.033, 0.046), 0.19, 0.016, 0.06, n=10),
                                   ("rings", "waves", "barcode",
                                    {"back": "shared/back_barcode", "sides": "shared/syrup_wrap"}), 5.0),
    "cholula_chipotle_hot_sauce": (_bottle((0.025, 0.025), 0.125, 0.011, 0.055),
                                   ("checker", "dots", "sunburst",
                                    {"sides": "shared/hot_sauce_wrap", "back": "shared/sauce_back"}), 20.0),
    "crystal_hot_sauce": (_bottle((0.026, 0.026), 0.12, 0.012, 0.05),
                          ("chevron", "dots", "plaid", {"sides": "shared/hot_sauce_wrap"}), 350.0),
    "honey_bunches_of_oats_honey_roasted": (_box(0.065, 0.19, 0.28),
                                            ("honeycomb", "stripes", "barcode",
                                             {"back": "shared/back_barcode", "front": "shared/hboo_front",
                                              "sides": "shared/hboo_sides"}), 45.0),
    "honey_bunches_of_oats_with_almonds": (_box(0.065, 0.19, 0.28),
                                           ("honeycomb", "stripes", "blobs",
                                            {"front": "shared/hboo_front", "sides": "shared/hboo_sides"}), 40.0),
    "mahatma_rice": (_box(0.07, 0.14, 0.25), ("blobs", "crosshatch", "rings", {}), 120.0),
    "pepto_bismol": (_bottle((0.026, 0.042), 0.17, 0.015, 0.04, n=8), ("waves", "plaid", "checker", {}), 320.0),
    "tapatio_hot_sauce": (_bottle((0.027, 0.027), 0.13, 0.012, 0.05),
                          ("crosshatch", "chevron", "sunburst", {"back": "shared/sauce_back"}), 10.0),
    "coca_cola_glass_bottle": (_bottle((0.031, 0.031), 0.14, 0.014, 0.09, n=12),
                               ("stripes", "rings", "dots", {}), 0.0),
    "pringles_bbq": (_bottle((0.038, 0.038), 0.23, 0.036, 0.012, n=12),
                     ("plaid", "sunburst", "honeycomb", {}), 15.0),
    "listerine_green": (_bottle((0.032, 0.045), 0.18, 0.014, 0.05, n=8),
                        ("dots", "waves", "stripes", {"sides": "shared/syrup_wrap"}), 130.0),
    "red_bull": (_bottle((0.027, 0.027), 0.13, 0.025, 0.012, n=10),
                 ("chevron", "barcode", "checker", {}), 210.0),
}
# The default stand-in's instances, in this order (the first is the default target).
DEFAULT_OBJECTS = tuple(_KNOWN)


def instance_spec(name: str) -> InstanceSpec:
    """Geometry and paint of an instance; names not in the table get a generic, name-seeded one."""
    if name not in AVD_INSTANCE_IDS or name == "background":
        raise ValueError(f"'data.synthetic.instances': {name!r} is not an AVD instance name "
                         f"(see instance_id_map.txt; e.g. aunt_jemima_original_syrup)")
    if name in _KNOWN:
        parts, (front, sides, back, shared), hue = _KNOWN[name]
        return InstanceSpec(name, parts, _paint(front, sides, back, shared=shared, name=name), hue)
    # Generic stand-in: a box or a bottle with name-seeded size and three distinct families.
    r = seeds.stream(0, "instance-shape", name)
    fams = [CATEGORY_NAMES[i] for i in r.choice(N_CATEGORIES, 3, replace=False)]
    if r.random() < 0.5:
        parts = _box(r.uniform(0.04, 0.09), r.uniform(0.08, 0.2), r.uniform(0.12, 0.3))
    else:
        rb = r.uniform(0.02, 0.045)
        parts = _bottle((rb, rb * r.uniform(0.6, 1.0)), r.uniform(0.1, 0.2), rb * 0.4, r.uniform(0.03, 0.06))
    return InstanceSpec(name, parts, _paint(*fams, name=name), float(r.uniform(0, 360)))


# ----------------------------------------------------------------------------------------------
# Built instances: faces with their textures

@dataclass(frozen=True, eq=False)  # holds arrays: identity, not value, equality
class Face:
    """A planar convex polygon with an outward normal and an optional texture.

    Texture mapping: texel (s, t) of an (H, W) image lies at ``origin + (s+0.5)/W * u_axis +
    (t+0.5)/H * v_axis`` (u to the viewer's right, v downwards), so the plane -> image homography
    is exact. Without a texture the face is filled with ``color`` (RGB floats in [0, 1]).
    """
    vertices: np.ndarray            # (n, 3), counter-clockwise seen from outside
    normal: np.ndarray              # (3,) unit, outward
    texture: np.ndarray | None = None
    origin: np.ndarray | None = None
    u_axis: np.ndarray | None = None
    v_axis: np.ndarray | None = None
    color: tuple = (0.5, 0.5, 0.5)
    label: int = 0                  # face index within its instance (for face-ID renders)
    region: str = ""                # front/left/back/right, "cap" or "" (scenery)
    family: int = -1                # texture family, -1 = plain colour


@dataclass(frozen=True, eq=False)  # holds arrays: identity, not value, equality
class Part:
    """A convex solid: its faces (back-face culling makes them non-overlapping on screen)."""
    faces: tuple[Face, ...]

    @property
    def centre(self) -> np.ndarray:
        return np.mean(np.concatenate([f.vertices for f in self.faces]), axis=0)


@dataclass(frozen=True, eq=False)  # holds arrays: identity, not value, equality
class Instance:
    name: str
    instance_id: int
    spec: InstanceSpec
    parts: tuple[Part, ...]

    @property
    def height(self) -> float:
        return self.spec.height

    @property
    def faces(self) -> tuple[Face, ...]:
        return tuple(f for p in self.parts for f in p.faces)


def _footprint(p: PartSpec) -> np.ndarray:
    """(n, 2) ccw polygon seen from above."""
    if p.kind == "box":
        return np.array([[p.rx, -p.ry], [p.rx, p.ry], [-p.rx, p.ry], [-p.rx, -p.ry]])
    # A face centred on +x (the front), unless that would put face normals exactly on the
    # 45-degree region borders (n divisible by 8): then a vertex sits on +x instead.
    off = 0.0 if p.n % 8 == 0 else -np.pi / p.n
    th = 2 * np.pi * np.arange(p.n) / p.n + off
    return np.stack([p.rx * np.cos(th), p.ry * np.sin(th)], axis=1)


def _region_of(normal_xy: np.ndarray) -> str:
    az = np.degrees(np.arctan2(normal_xy[1], normal_xy[0])) % 360.0
    if az < 45 or az >= 315:
        return "front"
    if az < 135:
        return "left"
    if az < 225:
        return "back"
    return "right"


def _hsv(h: float, s: float, v: float) -> tuple:
    return tuple(float(c) for c in hsv_to_rgb(h, s, v))


def prism_faces(foot: np.ndarray, z0: float, z1: float, *, side_color=(0.5, 0.5, 0.5),
                top_color=None, inward: bool = False) -> list[Face]:
    """Plain-coloured faces of a prism over a ccw footprint (used for scenery too).

    ``inward``: normals point inside (a room seen from within)."""
    out = []
    n = len(foot)
    sgn = -1.0 if inward else 1.0
    for i in range(n):
        a, b = foot[i], foot[(i + 1) % n]
        d = b - a
        nrm = sgn * np.array([d[1], -d[0], 0.0]) / np.hypot(*d)
        quad = np.array([[a[0], a[1], z0], [b[0], b[1], z0], [b[0], b[1], z1], [a[0], a[1], z1]])
        out.append(Face(quad if not inward else quad[::-1], nrm, color=side_color))
    top = np.column_stack([foot, np.full(n, z1)])
    bottom = np.column_stack([foot[::-1], np.full(n, z0)])
    tc = side_color if top_color is None else top_color
    out.append(Face(top if not inward else top[::-1], np.array([0, 0, sgn]), color=tc))
    out.append(Face(bottom if not inward else bottom[::-1], np.array([0, 0, -sgn]), color=side_color))
    return out


@lru_cache(maxsize=256)
def region_texture(key: str, family: int, seed: int, size: tuple[int, int]) -> np.ndarray:
    """The one image of a texture key (cached: every view of every writer reuses it)."""
    img = texture(family, seeds.stream(seed, "texture", key), size)
    img.setflags(write=False)
    return img


def build_instance(spec: InstanceSpec, seed: int) -> Instance:
    """Faces and textures of an instance in its object frame, deterministic for (name, seed)."""
    parts = []
    label = 0
    cap = _hsv(spec.cap_hue, 0.7, 0.75)
    for part in spec.parts:
        foot = _footprint(part)
        n = len(foot)
        edges = [foot[(i + 1) % n] - foot[i] for i in range(n)]
        regions = [_region_of(np.array([d[1], -d[0]])) for d in edges]
        extent: dict[str, float] = {}
        for r, d in zip(regions, edges):
            extent[r] = extent.get(r, 0.0) + float(np.hypot(*d))
        # Walk the sides counter-clockwise from a region border, so each region's faces take
        # consecutive slices of its texture (u runs to the viewer's right = ccw).
        start = next((i for i in range(n) if regions[i] != regions[i - 1]), 0)
        used: dict[str, float] = {r: 0.0 for r in extent}
        h = part.z1 - part.z0
        side_faces: dict[int, Face] = {}
        for i in [(start + k) % n for k in range(n)]:
            a, b = foot[i], foot[(i + 1) % n]
            d = edges[i]
            w = float(np.hypot(*d))
            nrm = np.array([d[1], -d[0], 0.0]) / w
            region = regions[i]
            bl, br = np.array([a[0], a[1], part.z0]), np.array([b[0], b[1], part.z0])
            tl, tr = bl + [0, 0, h], br + [0, 0, h]
            quad = np.array([bl, br, tr, tl])
            if part.painted:
                key, fam = spec.paint[region]
                # Texture size: the region's wrapped width x the part's height at PX_PER_M; a
                # shared key has a size of its own (one image on objects of different sizes).
                if key.startswith("shared/"):
                    size = (int(0.25 * PX_PER_M), int(0.15 * PX_PER_M))
                else:
                    size = (max(8, int(h * PX_PER_M)), max(8, int(extent[region] * PX_PER_M)))
                tex = region_texture(key, fam, seed, size)
                c0 = int(round(used[region] / extent[region] * tex.shape[1]))
                c1 = max(c0 + 1, int(round((used[region] + w) / extent[region] * tex.shape[1])))
                used[region] += w
                side_faces[i] = Face(quad, nrm, texture=tex[:, c0:c1], origin=tl, u_axis=br - bl,
                                     v_axis=bl - tl, label=label + i, region=region, family=fam)
            else:
                side_faces[i] = Face(quad, nrm, color=cap, label=label + i, region="cap")
        faces: list[Face] = [side_faces[i] for i in range(n)]
        label += n
        top_col = cap if not part.painted else _cap_colour(spec, seed)
        faces.append(Face(np.column_stack([foot, np.full(n, part.z1)]), np.array([0.0, 0, 1]),
                          color=top_col, label=label, region="cap"))
        label += 1
        faces.append(Face(np.column_stack([foot[::-1], np.full(n, part.z0)]), np.array([0.0, 0, -1]),
                          color=top_col, label=label, region="cap"))
        label += 1
        parts.append(Part(tuple(faces)))
    return Instance(spec.name, AVD_INSTANCE_IDS[spec.name], spec, tuple(parts))


def _cap_colour(spec: InstanceSpec, seed: int) -> tuple:
    """Top of a painted body: the front family's main colour, a little darker."""
    _, fam = spec.paint["front"]
    c1, _ = palette(fam, seeds.stream(seed, "cap", spec.name))
    return tuple(float(v) * 0.8 for v in c1)


@lru_cache(maxsize=64)
def make_instance(name: str, seed: int) -> Instance:
    """The instance both writers render (cached per process)."""
    return build_instance(instance_spec(name), int(seed))


def transform_faces(faces, R: np.ndarray, t: np.ndarray, label_offset: int = 0):
    """Faces moved by x -> R x + t (rigid), e.g. from the object frame into a room."""
    out = []
    for f in faces:
        out.append(Face(
            f.vertices @ R.T + t, R @ f.normal, f.texture,
            None if f.origin is None else R @ f.origin + t,
            None if f.u_axis is None else R @ f.u_axis,
            None if f.v_axis is None else R @ f.v_axis,
            f.color, f.label + label_offset, f.region, f.family))
    return tuple(out)


def rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
