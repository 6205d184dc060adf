"""The synthetic AVD room: walls, furniture, the instances on surfaces, clutter, capture grid.

Ground frame: metres, right-handed seen from above, z up, origin at the room's south-west
corner; the room spans [0, Lx] x [0, Ly]. Furniture follows a fixed template scaled to the room
(a coffee table in the middle, a counter along the north wall, a side table in the south-east
corner, a low shelf along the west wall), jittered by the seed. Instances go round-robin onto
the surfaces, the first one (the default target) on the coffee table so the capture grid
surrounds it; each gets a random yaw. An object point p maps into the room as
``Rot(yaw) p[:2] + position`` and ``p[2] + base height``.

Each scan name is another home: the layout jitter, placements and clutter are drawn from (seed,
scan). ``occluders`` small boxes stand right beside instances so some views see them partly
hidden. Clutter boxes and wall posters carry "clutter" textures (smooth noise with print blocks), never
the instances' face textures; the floor is planks. The capture grid covers the free floor at
``grid_step_m`` spacing, keeping clear of walls and furniture.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from loaders.synthetic.objects import (Face, make_instance, prism_faces, rot_z,
                                       transform_faces)
from loaders.synthetic.render import Light, Mesh
from pipeline.infra import seeds

WALL_HEIGHT_M = 2.5
WALL_MARGIN_M = 0.3       # grid points keep this far from the walls
CLEARANCE_M = 0.3         # ... and from furniture footprints
MIN_ROOM_M = 2.0


@dataclass(frozen=True)
class Furniture:
    name: str
    x0: float
    y0: float
    x1: float
    y1: float
    height: float
    kind: str                 # "table" (top slab + legs) or "cabinet" (solid block)
    color: tuple

    def distance(self, p: np.ndarray) -> float:
        """Distance from a ground point to the footprint rectangle (0 inside)."""
        dx = max(self.x0 - p[0], 0.0, p[0] - self.x1)
        dy = max(self.y0 - p[1], 0.0, p[1] - self.y1)
        return float(np.hypot(dx, dy))


@dataclass(frozen=True)
class Placement:
    name: str
    instance_id: int
    position: tuple           # (x, y) metres, ground frame
    yaw_deg: float            # object frame -> ground, about up
    base_height: float        # metres: the supporting surface's height
    surface: str
    radius: float


@dataclass(frozen=True)
class Clutter:
    position: tuple
    yaw_deg: float
    base_height: float
    size: tuple               # (sx, sy, sz) metres
    key: str                  # texture key
    surface: str


@dataclass(frozen=True)
class Room:
    size: tuple
    furniture: tuple
    placements: tuple
    clutter: tuple
    grid_ij: np.ndarray       # (n, 2) integer grid indices
    grid_xy: np.ndarray       # (n, 2) metres
    grid_step: float
    seed: int

    def placement(self, name: str) -> Placement:
        return next(p for p in self.placements if p.name == name)


def _footprint_radius(name: str, seed: int) -> float:
    inst = make_instance(name, seed)
    pts = np.concatenate([f.vertices for f in inst.faces])
    return float(np.hypot(pts[:, 0], pts[:, 1]).max())


def _layout(Lx: float, Ly: float, rng: np.random.Generator) -> list[Furniture]:
    j = lambda s: float(rng.uniform(-s, s))  # noqa: E731 - small jitter
    cx, cy = 0.5 * Lx + j(0.1), 0.45 * Ly + j(0.1)
    wood = (0.45 + j(0.05), 0.3 + j(0.04), 0.18)
    cl = 0.08 * Lx + j(0.05)
    sh = 0.15 * Ly + j(0.05)
    return [
        Furniture("coffee_table", cx - 0.35, cy - 0.22, cx + 0.35, cy + 0.22, 0.45 + j(0.03), "table", wood),
        Furniture("counter", cl, Ly - 0.5, cl + min(1.4, 0.45 * Lx), Ly, 0.9, "cabinet", (0.82, 0.8, 0.74)),
        Furniture("side_table", Lx - 0.5, 0.05, Lx - 0.05, 0.5, 0.65 + j(0.03), "table", (0.3, 0.22, 0.16)),
        Furniture("shelf", 0.0, sh, 0.35, sh + min(1.0, 0.4 * Ly), 0.6, "cabinet", (0.55, 0.6, 0.66)),
    ]


def _place_on(surface: Furniture, radius: float, taken: list[tuple], rng: np.random.Generator,
              tries: int = 200):
    """A random spot on the surface, inside its edge, away from what is already there."""
    m = radius + 0.03
    if surface.x1 - surface.x0 < 2 * m or surface.y1 - surface.y0 < 2 * m:
        return None
    for _ in range(tries):
        p = np.array([rng.uniform(surface.x0 + m, surface.x1 - m), rng.uniform(surface.y0 + m, surface.y1 - m)])
        if all(np.hypot(*(p - q)) >= radius + r + 0.04 for q, r in taken):
            return p
    return None


def scan_instances(instances, scans, scan: str, per_scan: int) -> tuple[str, ...]:
    """The instances placed in ``scan``: scan k of S takes ``per_scan`` consecutive instances
    (cyclically) from index round(k * n / S); ``per_scan`` 0 (or >= n) = all of them. Every
    instance lands in some scan when per_scan * S >= n (checked by the config)."""
    instances, scans = tuple(instances), tuple(scans)
    n = len(instances)
    if scan not in scans:
        raise ValueError(f"'data.scans' does not list {scan!r}")
    if per_scan <= 0 or per_scan >= n:
        return instances
    start = int(round(scans.index(scan) * n / len(scans)))
    return tuple(instances[(start + j) % n] for j in range(per_scan))


def make_room(instances, cfg, seed: int, scan: str = "") -> Room:
    """The room for these instances; ``cfg`` is the ``data.synthetic`` config section. Each scan
    name gets its own furniture jitter, placements and clutter (another home)."""
    Lx, Ly = (float(v) for v in cfg.room_size_m)
    if min(Lx, Ly) < MIN_ROOM_M:
        raise ValueError(f"'data.synthetic.room_size_m' = {list(cfg.room_size_m)}: each side must be at "
                         f"least {MIN_ROOM_M} m to hold the furniture")
    # Home_001_1 (and an unnamed scan) keeps the layout stream it had before there were several
    # scans, so its room is the one earlier runs and tests know; any other scan is another home.
    rng = seeds.stream(seed, "room-layout") if scan in ("", "Home_001_1") else seeds.stream(seed, "room-layout", scan)
    furniture = _layout(Lx, Ly, rng)
    surfaces = furniture  # every piece has a top to stand things on
    taken: dict[str, list] = {f.name: [] for f in furniture}

    placements = []
    for k, name in enumerate(instances):
        r = _footprint_radius(name, seed)
        for s in range(len(surfaces)):
            surf = surfaces[(k + s) % len(surfaces)]
            p = _place_on(surf, r, taken[surf.name], rng)
            if p is not None:
                break
        else:
            raise ValueError(f"'data.synthetic.instances': no room left on the furniture for {name!r} "
                             f"({len(instances)} instances); enlarge 'data.synthetic.room_size_m'")
        taken[surf.name].append((p, r))
        inst = make_instance(name, seed)
        placements.append(Placement(name, inst.instance_id, (float(p[0]), float(p[1])),
                                    float(rng.uniform(0.0, 360.0)), surf.height, surf.name, r))

    clutter = _occluders(placements, furniture, taken, cfg.occluders, rng)
    for k in range(cfg.distractors):
        sx, sy, sz = rng.uniform(0.06, 0.3), rng.uniform(0.06, 0.25), rng.uniform(0.05, 0.35)
        r = 0.5 * float(np.hypot(sx, sy))
        spot, surf_name, base = None, "floor", 0.0
        if k % 2 == 0:  # half on the furniture, beside the instances
            surf = surfaces[int(rng.integers(len(surfaces)))]
            spot = _place_on(surf, r, taken[surf.name], rng, tries=50)
            if spot is not None:
                taken[surf.name].append((spot, r))
                surf_name, base = surf.name, surf.height
        if spot is None:  # on the floor along a wall, inside the grid's wall margin
            for _ in range(100):
                wall = int(rng.integers(4))
                along = rng.uniform(0.3, (Lx if wall in (0, 2) else Ly) - 0.3)
                off = r + 0.01
                spot = np.array([[along, off], [Lx - off, along], [along, Ly - off], [off, along]][wall])
                if all(f.distance(spot) > r + 0.02 for f in furniture) and \
                        all(np.hypot(*(spot - np.array(c.position))) > r + 0.3 for c in clutter):
                    break
            else:
                continue
            sz = rng.uniform(0.2, 0.6)  # floor clutter: bins, boxes, a bag
        clutter.append(Clutter((float(spot[0]), float(spot[1])), float(rng.uniform(0, 90)), base,
                               (float(sx), float(sy), float(sz)), f"clutter/{k}", surf_name))

    step = float(cfg.grid_step_m)
    ni = int(np.floor((Lx - 2 * WALL_MARGIN_M) / step + 1e-9)) + 1
    nj = int(np.floor((Ly - 2 * WALL_MARGIN_M) / step + 1e-9)) + 1
    ij, xy = [], []
    for gj in range(nj):
        for gi in range(ni):
            p = np.array([WALL_MARGIN_M + gi * step, WALL_MARGIN_M + gj * step])
            if any(f.distance(p) < CLEARANCE_M for f in furniture):
                continue
            if any(c.surface == "floor" and np.hypot(*(p - np.array(c.position))) < CLEARANCE_M + 0.5 * max(c.size[:2])
                   for c in clutter):
                continue
            ij.append((gi, gj))
            xy.append(p)
    if not ij:
        raise ValueError(f"'data.synthetic.room_size_m' / 'grid_step_m': no free grid point in a "
                         f"{Lx} x {Ly} m room")
    return Room((Lx, Ly), tuple(furniture), tuple(placements), tuple(clutter),
                np.array(ij, dtype=np.int64), np.array(xy, dtype=np.float64), step, int(seed))


def _occluders(placements, furniture, taken, n: int, rng: np.random.Generator) -> list[Clutter]:
    """Small, low boxes right beside instances (2-6 cm gap), so views from their side see the
    instance partly hidden, as behind a mug or a packet on a real table."""
    by_name = {f.name: f for f in furniture}
    out = []
    for k in range(min(n, len(placements))):
        p = placements[k % len(placements)]
        surf = by_name[p.surface]
        sx, sy = rng.uniform(0.05, 0.1), rng.uniform(0.05, 0.12)
        r = 0.5 * float(np.hypot(sx, sy))
        for _ in range(60):
            a = rng.uniform(0, 2 * np.pi)
            d = p.radius + r + rng.uniform(0.02, 0.06)
            q = np.array(p.position) + d * np.array([np.cos(a), np.sin(a)])
            inside = surf.x0 + r <= q[0] <= surf.x1 - r and surf.y0 + r <= q[1] <= surf.y1 - r
            if inside and all(np.hypot(*(q - np.asarray(c))) >= r + rc + 0.01 for c, rc in taken[surf.name]):
                taken[surf.name].append((q, r))
                out.append(Clutter((float(q[0]), float(q[1])), float(rng.uniform(0, 90)), surf.height,
                                   (float(sx), float(sy), float(rng.uniform(0.05, 0.12))),
                                   f"occluder/{k}", surf.name))
                break
    return out


# ----------------------------------------------------------------------------------------------
# Appearance

@lru_cache(maxsize=64)
def clutter_texture(key: str, seed: int, size: tuple[int, int] = (128, 128)) -> np.ndarray:
    """Non-periodic "packaging" texture: smooth colour noise with a few solid print blocks.
    Deliberately unlike the periodic source-domain families on the instances."""
    rng = seeds.stream(seed, "clutter-texture", key)
    h, w = size
    base = rng.uniform(0.2, 0.9, 3)
    low = cv2.resize(rng.normal(0, 0.12, (4, 4, 3)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    img = np.clip(base + low, 0, 1)
    for _ in range(int(rng.integers(2, 6))):
        x0, y0 = int(rng.integers(0, w - 8)), int(rng.integers(0, h - 8))
        img[y0:y0 + int(rng.integers(4, h // 3)), x0:x0 + int(rng.integers(8, w // 2))] = rng.uniform(0, 1, 3)
    img += rng.normal(0, 0.02, img.shape)
    out = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=4)
def floor_texture(seed: int, size: tuple[int, int] = (768, 768)) -> np.ndarray:
    """Wooden planks: bands with per-plank tone and a fine grain."""
    rng = seeds.stream(seed, "floor")
    h, w = size
    planks = 12
    tone = rng.uniform(0.85, 1.15, planks)
    y = np.arange(h)
    band = tone[(y * planks // h)][:, None]
    grain = cv2.resize(rng.normal(0, 1, (h // 2, 8)).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    v = np.clip(band * (0.55 + 0.04 * grain), 0, 1)
    v[(y * planks) % h < planks * 2] *= 0.7  # dark joints between planks
    col = np.array([0.62, 0.45, 0.3])
    out = (np.clip(v[..., None] * col, 0, 1) * 255).astype(np.uint8)
    out.setflags(write=False)
    return out


def _textured_box(centre_xy, yaw_deg, base, size, tex) -> tuple[Face, ...]:
    """A box whose four sides and top carry (slices of) one texture."""
    sx, sy, sz = size
    foot = np.array([[sx / 2, -sy / 2], [sx / 2, sy / 2], [-sx / 2, sy / 2], [-sx / 2, -sy / 2]])
    faces = []
    for f in prism_faces(foot, 0.0, sz):
        if abs(f.normal[2]) < 0.5:  # side: vertices bl, br, tr, tl
            bl, br, tr, tl = f.vertices
            faces.append(Face(f.vertices, f.normal, texture=tex, origin=tl, u_axis=br - bl, v_axis=bl - tl))
        elif f.normal[2] > 0:
            v = f.vertices  # top: a ccw rectangle
            faces.append(Face(v, f.normal, texture=tex, origin=v[3], u_axis=v[2] - v[3], v_axis=v[0] - v[3]))
        else:
            faces.append(f)
    return transform_faces(faces, rot_z(yaw_deg), np.array([centre_xy[0], centre_xy[1], base]))


def _furniture_meshes(f: Furniture) -> list[Mesh]:
    col = f.color
    top_col = tuple(min(1.0, c * 1.1) for c in col)
    if f.kind == "cabinet":
        foot = np.array([[f.x0, f.y0], [f.x1, f.y0], [f.x1, f.y1], [f.x0, f.y1]])
        return [Mesh(tuple(prism_faces(foot, 0.0, f.height, side_color=col, top_color=top_col)))]
    slab = 0.035
    foot = np.array([[f.x0, f.y0], [f.x1, f.y0], [f.x1, f.y1], [f.x0, f.y1]])
    out = [Mesh(tuple(prism_faces(foot, f.height - slab, f.height, side_color=col, top_color=top_col)))]
    leg = 0.04
    for x, y in ((f.x0 + 0.03, f.y0 + 0.03), (f.x1 - 0.03 - leg, f.y0 + 0.03),
                 (f.x1 - 0.03 - leg, f.y1 - 0.03 - leg), (f.x0 + 0.03, f.y1 - 0.03 - leg)):
        lf = np.array([[x, y], [x + leg, y], [x + leg, y + leg], [x, y + leg]])
        out.append(Mesh(tuple(prism_faces(lf, 0.0, f.height - slab, side_color=tuple(c * 0.8 for c in col)))))
    return out


def _shell(room: Room) -> Mesh:
    """Floor, walls and ceiling as one inward-facing shell."""
    Lx, Ly = room.size
    foot = np.array([[0, 0], [Lx, 0], [Lx, Ly], [0, Ly]], dtype=float)
    faces = prism_faces(foot, 0.0, WALL_HEIGHT_M, inward=True, side_color=(0.86, 0.83, 0.76),
                        top_color=(0.93, 0.93, 0.92))
    wall_tints = [(0.86, 0.83, 0.76), (0.8, 0.84, 0.86), (0.86, 0.83, 0.76), (0.88, 0.8, 0.72)]
    out = []
    for k, f in enumerate(faces[:4]):
        out.append(Face(f.vertices, f.normal, color=wall_tints[k]))
    out.append(faces[4])  # ceiling (inward normal points down)
    # Floor: planks texture stretched over the room (u along x, v along -y).
    tex = floor_texture(room.seed)
    out.append(Face(faces[5].vertices, faces[5].normal, texture=tex, origin=np.array([0.0, Ly, 0.0]),
                    u_axis=np.array([Lx, 0.0, 0.0]), v_axis=np.array([0.0, -Ly, 0.0])))
    return Mesh(tuple(out), 0, shell=True)


def _posters(room: Room) -> list[Mesh]:
    """Two framed pictures on the walls (scenery, clutter textures)."""
    Lx, Ly = room.size
    rng = seeds.stream(room.seed, "posters")
    out = []
    for k, (x, y, yaw) in enumerate(((0.6 * Lx, 0.012, 90.0), (Lx - 0.012, 0.6 * Ly, 180.0))):
        w, h = rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.6)
        tex = clutter_texture(f"poster/{k}", room.seed, (96, 128))
        faces = _textured_box((x, y), yaw, 1.2, (0.02, w, h), tex)
        out.append(Mesh(faces))
    return out


def room_meshes(room: Room) -> list[Mesh]:
    """Every mesh of the room; instances carry their AVD instance id as label."""
    meshes = [_shell(room)]
    for f in room.furniture:
        meshes += _furniture_meshes(f)
    meshes += _posters(room)
    for c in room.clutter:
        tex = clutter_texture(c.key, room.seed)
        meshes.append(Mesh(_textured_box(c.position, c.yaw_deg, c.base_height, c.size, tex)))
    for p in room.placements:
        meshes += placed_meshes(p, room.seed)
    return meshes


def placed_meshes(p: Placement, seed: int) -> list[Mesh]:
    """An instance's parts moved into the room: x -> Rot(yaw) x + (position, base height)."""
    inst = make_instance(p.name, seed)
    R, t = rot_z(p.yaw_deg), np.array([p.position[0], p.position[1], p.base_height])
    return [Mesh(transform_faces(part.faces, R, t), inst.instance_id) for part in inst.parts]


# Dimmer, warmer, one directional light (a window): the dataset shift from the BigBIRD rig.
ROOM_LIGHT = Light(direction=(-0.45, 0.35, 0.82), color=(1.0, 0.86, 0.68), ambient=0.36, diffuse=0.5)
