"""Write the synthetic room as one Active Vision Dataset scan (docs/formats/avd.md).

``<root>/instance_id_map.txt`` (the real 34-line map) and ``<root>/<scan>/``: ``jpg_rgb/`` (15-digit
names: type, scene, scan, 1-based index, camera ``01``, type ``01``), ``annotations.json`` (boxes
``[x0, y0, x1, y1, id, difficulty]`` for every visible instance, x1/y1 exclusive, plus move
pointers), ``image_structs.mat`` (16 fields, sorted by name, and ``scale``),
``present_instance_names.txt`` and a COLMAP ``cameras.txt``.

Capture: the robot stops at each free grid point (a cluster of 12 consecutive indices) and turns
counter-clockwise in 30 degree steps (index + 1 = heading + 30 deg), camera ``avd_camera_height_m``
above the floor, pitched down by ``avd_pitch_deg``. Reconstruction ("recon") coordinates follow
COLMAP (X_cam = R X + t) with x = ground x, y = -height (down), z = ground y, in units of
``SCALE_MM`` millimetres (the file's ``scale``), so they are not millimetres themselves.

Interpolated entries (empty R, t, quat; world_pos and direction filled by the authors' rule) come
in opposite pairs (j, j + 6) within a cluster, at least two registered images per cluster. With
pairs, the registered cameras' image-down axes still average to exactly -up even when the camera
is pitched, so a reader's estimated ground frame is exact.
"""
from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import scipy.io

from loaders.avd import KINECT_K, KINECT_SIZE, STRUCT_FIELDS, difficulty
from loaders.synthetic.bigbird_writer import encode_jpeg
from loaders.synthetic.objects import AVD_INSTANCE_MAP_TEXT
from loaders.synthetic.render import Camera, render
from loaders.synthetic.scene import ROOM_LIGHT, Room, make_room, room_meshes
from pipeline.infra.cache import write_bytes, write_json, write_text
from pipeline.infra import seeds

CLUSTER = 12                      # images per grid point, 30 degrees apart
SCALE_MM = 331.7                  # mm per recon unit (the file's `scale`)
# ground (x, y, up) -> recon (x, -up, y): right-handed, recon y points down.
M_GROUND_TO_RECON = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MIN_VISIBLE_PX = 30               # fewer visible pixels than this: no box
NOISE_STD = 2.5                   # sensor noise, grey levels
MOVE_KEYS = ("rotate_ccw", "rotate_cw", "forward", "backward", "left", "right")
_SCAN_RE = re.compile(r"^(Home|Office|Gen)_(\d{3})_(\d)$")
_TYPE_DIGIT = {"Home": "0", "Office": "1", "Gen": "2"}


def name_prefix(scan: str) -> str:
    """The first five digits of a scan's image names (type, scene, scan number)."""
    m = _SCAN_RE.match(scan)
    if not m:
        raise ValueError(f"'data.scans' names {scan!r}, which is not an AVD scan name like 'Home_001_1'")
    return _TYPE_DIGIT[m.group(1)] + m.group(2) + m.group(3)


def image_name(prefix: str, index: int) -> str:
    return f"{prefix}{index:06d}0101.jpg"


def intrinsics(width: int, height: int) -> np.ndarray:
    """The authors' Kinect calibration scaled to the image size (as the AVD reader scales it)."""
    return np.diag([width / KINECT_SIZE[0], height / KINECT_SIZE[1], 1.0]) @ KINECT_K


@dataclass(frozen=True)
class Shot:
    name: str
    index: int                    # 1-based image index
    cluster: int                  # 0-based grid point
    j: int                        # 0..11 turn step
    position: tuple               # (x, y) ground metres (camera centre)
    heading_deg: float            # optical axis direction, ccw from ground x
    registered: bool


@dataclass(frozen=True)
class Nuisance:
    """Capture nuisance of a scan (``data.synthetic.avd_*``)."""
    auto_exposure: float = 0.0      # gain pulls the image mean this far towards mid-grey
    blur_fraction: float = 0.0      # share of images with motion blur
    blur_px: int = 1                # longest blur streak
    box_jitter_px: int = 0          # annotation box sides moved by up to this


@dataclass(frozen=True, eq=False)  # hashed by identity: plans are cached per process
class ScanPlan:
    scan: str
    room: Room
    shots: tuple
    K: np.ndarray
    width: int
    height: int
    camera_height: float
    pitch_deg: float
    seed: int
    quality: int
    nuisance: Nuisance = Nuisance()

    def camera(self, shot: Shot) -> Camera:
        """The ground-frame camera of a shot (x right, y down, z along the optical axis)."""
        phi, p = math.radians(shot.heading_deg), math.radians(self.pitch_deg)
        f = np.array([math.cos(phi) * math.cos(p), math.sin(phi) * math.cos(p), -math.sin(p)])
        right = np.array([math.sin(phi), -math.cos(phi), 0.0])
        down = np.cross(f, right)
        R = np.stack([right, down, f])
        c = np.array([shot.position[0], shot.position[1], self.camera_height])
        return Camera(self.K, R, -R @ c, self.width, self.height)

    def recon_pose(self, shot: Shot) -> tuple[np.ndarray, np.ndarray]:
        """COLMAP (R, t) in recon coordinates (units of SCALE_MM millimetres)."""
        cam = self.camera(shot)
        return cam.R @ M_GROUND_TO_RECON.T, cam.t * (1000.0 / SCALE_MM)


def plan_scan(cfg, scan: str, seed: int, instances=None) -> ScanPlan:
    """Room, capture grid and every shot's pose; ``cfg`` is the ``data.synthetic`` section and
    ``instances`` the ones placed in this scan (default: all of ``cfg.instances``)."""
    return _plan_scan(cfg, scan, int(seed), tuple(cfg.instances if instances is None else instances))


@lru_cache(maxsize=4)
def _plan_scan(cfg, scan: str, seed: int, instances: tuple) -> ScanPlan:
    prefix = name_prefix(scan)
    room = make_room(instances, cfg, seed, scan)
    n = len(room.grid_xy) * CLUSTER
    # Interpolated images: opposite pairs (j, j+6), at most 5 pairs of a cluster (>= 2 registered).
    rng = seeds.stream(seed, "interpolated")
    want = int(round(cfg.interpolated_fraction * n / 2))
    dropped: dict[int, set] = {}
    for flat in rng.permutation(len(room.grid_xy) * 6):
        if want <= 0:
            break
        k, p = divmod(int(flat), 6)
        if len(dropped.setdefault(k, set())) < 5:
            dropped[k].add(p)
            want -= 1
    shots = []
    for k, (x, y) in enumerate(room.grid_xy):
        # Reconstructed poses are never exactly on the grid: a little per-vertex jitter.
        r = seeds.stream(seed, "vertex", k)
        phi0 = float(r.normal(0.0, 1.5))
        pos = (float(x + r.normal(0, 0.008)), float(y + r.normal(0, 0.008)))
        for j in range(CLUSTER):
            idx = k * CLUSTER + j + 1
            shots.append(Shot(image_name(prefix, idx), idx, k, j, pos, phi0 + 30.0 * j,
                              (j % 6) not in dropped.get(k, set())))
    K = intrinsics(cfg.avd_width, cfg.avd_height)
    nuisance = Nuisance(float(cfg.avd_auto_exposure), float(cfg.avd_motion_blur_fraction),
                        int(cfg.avd_motion_blur_px), int(cfg.avd_box_jitter_px))
    return ScanPlan(scan, room, tuple(shots), K, cfg.avd_width, cfg.avd_height,
                    float(cfg.avd_camera_height_m), float(cfg.avd_pitch_deg), seed, int(cfg.jpeg_quality),
                    nuisance)


@lru_cache(maxsize=4)
def _meshes(plan: ScanPlan):
    return room_meshes(plan.room)


def visible_boxes(ids: np.ndarray, instance_ids) -> list[list[int]]:
    """[x0, y0, x1, y1, id, difficulty] of each instance with enough visible pixels (x1, y1
    exclusive: ``img[y0:y1, x0:x1]`` holds every visible pixel)."""
    out = []
    # One count of every label, then each box from its mask's row and column projections: the
    # same boxes as np.nonzero's coordinates at a quarter of its CPU time (4.5 -> 1.1 ms a shot).
    iids = sorted(instance_ids)
    counts = np.bincount(ids.ravel(), minlength=max(iids, default=0) + 1) if ids.size else np.zeros(1, int)
    for iid in iids:
        if iid >= len(counts) or iid < 0 or counts[iid] < MIN_VISIBLE_PX:
            continue
        mask = ids == iid
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        x0, y0, x1, y1 = int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1
        out.append([x0, y0, x1, y1, int(iid), difficulty(x0, y0, x1, y1)])
    return out


@lru_cache(maxsize=2)
def _noise_bank(seed: int, size: int) -> np.ndarray:
    """Gaussian sensor noise drawn once per process; each image takes a slice at its own random
    offset (drawing fresh normals per image cost more than rendering it)."""
    bank = seeds.stream(seed, "avd-noise-bank").standard_normal(4 * size, dtype=np.float32) * NOISE_STD
    bank.setflags(write=False)
    return bank


def capture(rgb: np.ndarray, nz: Nuisance, rng: np.random.Generator) -> np.ndarray:
    """Auto-exposure (the gain pulls the mean brightness towards mid-grey, with some jitter, as a
    consumer camera's AE does) and, on some frames, a motion-blur streak along a random direction
    (the robot turning or braking)."""
    if nz.auto_exposure > 0:
        mean = max(float(rgb.mean()), 1.0)
        gain = (118.0 / mean) ** nz.auto_exposure * float(np.exp(rng.normal(0.0, 0.04)))
        rgb = cv2.convertScaleAbs(rgb, alpha=float(np.clip(gain, 0.5, 2.5)))
    if nz.blur_fraction > 0 and rng.random() < nz.blur_fraction and nz.blur_px > 1:
        n = int(rng.integers(3, nz.blur_px + 1))
        k = np.zeros((n, n), np.float32)
        c = (n - 1) / 2
        a = rng.uniform(-0.35, 0.35)  # mostly horizontal: the robot turns in place
        d = np.array([np.cos(a), np.sin(a)]) * c
        cv2.line(k, (int(round(c - d[0])), int(round(c - d[1]))), (int(round(c + d[0])), int(round(c + d[1]))), 1.0)
        rgb = cv2.filter2D(rgb, -1, k / k.sum(), borderType=cv2.BORDER_REFLECT)
    return rgb


def render_shot(plan: ScanPlan, shot: Shot):
    """(RGB with auto-exposure, motion blur and sensor noise, ID buffer) of one shot."""
    res = render(plan.camera(shot), _meshes(plan), ROOM_LIGHT, (0, 0, 0))
    rng = seeds.stream(plan.seed, "avd-noise", shot.name)
    n = res.rgb.size
    off = int(rng.integers(0, 3 * n))
    rgb = capture(res.rgb, plan.nuisance, rng)
    noise = _noise_bank(plan.seed, n)[off:off + n].reshape(res.rgb.shape)
    return cv2.add(rgb, noise, dtype=cv2.CV_8U), res.ids


def jitter_boxes(boxes: list[list[int]], px: int, width: int, height: int, rng: np.random.Generator) -> list:
    """Annotation error: each side moved by up to ``px`` pixels, kept inside the image and at least
    2 px wide/high; the difficulty is recomputed from the jittered box."""
    if px <= 0:
        return boxes
    out = []
    for x0, y0, x1, y1, iid, _ in boxes:
        d = rng.integers(-px, px + 1, 4)
        nx0, ny0 = int(np.clip(x0 + d[0], 0, width - 2)), int(np.clip(y0 + d[1], 0, height - 2))
        nx1, ny1 = int(np.clip(x1 + d[2], nx0 + 2, width)), int(np.clip(y1 + d[3], ny0 + 2, height))
        out.append([nx0, ny0, nx1, ny1, iid, difficulty(nx0, ny0, nx1, ny1)])
    return out


def write_shot(folder: Path, plan: ScanPlan, shot: Shot) -> tuple[list, int]:
    """Render one shot into ``<folder>/jpg_rgb/``; returns (boxes, bytes written)."""
    rgb, ids = render_shot(plan, shot)
    jpg = encode_jpeg(rgb, plan.quality)
    write_bytes(folder / "jpg_rgb" / shot.name, jpg)
    boxes = visible_boxes(ids, [p.instance_id for p in plan.room.placements])
    rng = seeds.stream(plan.seed, "avd-box-jitter", shot.name)
    return jitter_boxes(boxes, plan.nuisance.box_jitter_px, plan.width, plan.height, rng), len(jpg)


def move_pointers(plan: ScanPlan) -> dict[str, dict[str, str]]:
    """annotations.json moves: rotations within a cluster; translations to the 4-neighbour grid
    point nearest the move's direction, same turn step ('' where there is no grid point)."""
    by_ij = {tuple(ij): k for k, ij in enumerate(plan.room.grid_ij.tolist())}
    names = {(s.cluster, s.j): s.name for s in plan.shots}
    steps = ((1, 0), (0, 1), (-1, 0), (0, -1))  # +x, +y, -x, -y: ccw quarter turns
    out = {}
    for s in plan.shots:
        ij = plan.room.grid_ij[s.cluster]
        q = int(round((30.0 * s.j) / 90.0)) % 4  # quarter turn nearest the heading
        mv = {"rotate_ccw": names[(s.cluster, (s.j + 1) % CLUSTER)],
              "rotate_cw": names[(s.cluster, (s.j - 1) % CLUSTER)]}
        for key, dq in (("forward", 0), ("left", 1), ("backward", 2), ("right", 3)):
            d = steps[(q + dq) % 4]
            k = by_ij.get((int(ij[0] + d[0]), int(ij[1] + d[1])))
            mv[key] = "" if k is None else names[(k, s.j)]
        out[s.name] = mv
    return out


def quat_from_R(R: np.ndarray) -> np.ndarray:
    """[qw, qx, qy, qz] of a rotation matrix, qw >= 0 (COLMAP's convention)."""
    m = R
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q if q[0] >= 0 else -q


def struct_records(plan: ScanPlan, moves: dict) -> list[dict]:
    """The 16 image_structs fields per image, sorted by name (docs/formats/avd.md §4, §6)."""
    poses = {s.name: plan.recon_pose(s) for s in plan.shots}
    by_cluster: dict[int, list[Shot]] = {}
    for s in plan.shots:
        by_cluster.setdefault(s.cluster, []).append(s)
    recs = []
    colmap_id = 0
    for s in sorted(plan.shots, key=lambda s: s.name):
        R, t = poses[s.name]
        if s.registered:
            colmap_id += 1
            world = -R.T @ t
            direction = R.T @ np.array([0.0, 0.0, 1.0])
            rec = {"t": t.reshape(3, 1), "R": R, "quat": quat_from_R(R).reshape(4, 1),
                   "image_id": str(colmap_id), "camera_id": "1"}
        else:
            # The authors' interpolation: mean registered position of the cluster; the direction of
            # the nearest registered smaller index (cyclically), turned by 30 deg per step in x-z.
            cl = by_cluster[s.cluster]
            regs = [c for c in cl if c.registered]
            world = np.mean([-poses[c.name][0].T @ poses[c.name][1] for c in regs], axis=0)
            dist = next(d for d in range(1, CLUSTER) if cl[(s.j - d) % CLUSTER].registered)
            src = cl[(s.j - dist) % CLUSTER]
            dx, dy, dz = poses[src.name][0].T @ np.array([0.0, 0.0, 1.0])
            th = math.radians(30.0 * dist)
            direction = np.array([dx * math.cos(th) - dz * math.sin(th), dy,
                                  dz * math.cos(th) + dx * math.sin(th)])
            rec = {"t": np.zeros((0, 0)), "R": np.zeros((0, 0)), "quat": np.zeros((0, 0)),
                   "image_id": "", "camera_id": ""}
        mv = moves[s.name]
        nb = lambda k: mv[k] if mv[k] else -1.0  # noqa: E731 - the pipeline's "no neighbour" is -1
        rec.update({"image_name": s.name, "world_pos": world.reshape(3, 1),
                    "direction": direction.reshape(3, 1),
                    "scaled_world_pos": (world * SCALE_MM).reshape(3, 1),
                    "cluster_id": float(s.cluster + 1),
                    "rotate_cw": nb("rotate_cw"), "rotate_ccw": nb("rotate_ccw"),
                    "translate_forward": nb("forward"), "translate_backward": nb("backward"),
                    "translate_right": nb("right"), "translate_left": nb("left")})
        recs.append(rec)
    return recs


def write_image_structs(path: Path, recs: list[dict]) -> None:
    arr = np.empty((1, len(recs)), dtype=[(f, "O") for f in STRUCT_FIELDS])
    for i, r in enumerate(recs):
        for f in STRUCT_FIELDS:
            arr[0, i][f] = r[f]
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"image_structs": arr, "scale": np.array([[SCALE_MM]])})
    data = bytearray(buf.getvalue())
    # The 116-byte descriptive header text carries a creation time; a fixed text keeps the file
    # identical for a seed (MATLAB only requires the text to start with 'MATLAB 5.0 MAT-file').
    data[:116] = b"MATLAB 5.0 MAT-file, written by viewfuse (synthetic AVD stand-in)".ljust(116)
    write_bytes(path, bytes(data))


def write_scan_metadata(root: str | Path, plan: ScanPlan, boxes: dict[str, list]) -> None:
    """Everything but the JPEGs: the root id map, annotations, structs, present names, cameras."""
    root = Path(root)
    folder = root / plan.scan
    write_text(root / "instance_id_map.txt", AVD_INSTANCE_MAP_TEXT)
    moves = move_pointers(plan)
    ann = {}
    for s in sorted(plan.shots, key=lambda s: s.name):
        ann[s.name] = {"bounding_boxes": boxes[s.name], **{k: moves[s.name][k] for k in MOVE_KEYS}}
    write_json(folder / "annotations.json", ann)
    write_image_structs(folder / "image_structs.mat", struct_records(plan, moves))
    write_text(folder / "present_instance_names.txt", "".join(f"{p.name}\n" for p in plan.room.placements))
    fx, fy, cx, cy = plan.K[0, 0], plan.K[1, 1], plan.K[0, 2], plan.K[1, 2]
    write_text(folder / "cameras.txt",
               "# Camera list with one line of data per camera:\n"
               "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
               "# Number of cameras: 1\n"
               f"1 OPENCV {plan.width} {plan.height} {fx:.6f} {fy:.6f} {cx:.6f} {cy:.6f} 0 0 0 0\n")


def truth(plan: ScanPlan) -> dict:
    """The ground-truth sidecar (no reader needs it): instance poses, grid, camera."""
    room = plan.room
    return {
        "scan": plan.scan,
        "frame": "ground = (recon x, recon z) * scale / 1000 m; up = -recon y",
        "recon_scale_mm": SCALE_MM,
        "image_size": [plan.width, plan.height],
        "intrinsics": plan.K.tolist(),
        "camera_height_m": plan.camera_height,
        "pitch_deg": plan.pitch_deg,
        "room_size_m": list(room.size),
        "grid_step_m": room.grid_step,
        "grid_points": room.grid_xy.tolist(),
        "instances": {p.name: {"id": p.instance_id, "position": list(p.position), "yaw_deg": p.yaw_deg,
                               "base_height_m": p.base_height, "surface": p.surface}
                      for p in room.placements},
        "furniture": [{"name": f.name, "box": [f.x0, f.y0, f.x1, f.y1], "height_m": f.height}
                      for f in room.furniture],
        "images": len(plan.shots),
        "interpolated": sum(not s.registered for s in plan.shots),
    }


def write_avd_scan(root: str | Path, cfg, scan: str, seed: int, progress=None, instances=None) -> ScanPlan:
    """Write a whole scan serially (the data stage spreads ``write_shot`` over processes)."""
    plan = plan_scan(cfg, scan, seed, instances)
    folder = Path(root) / scan
    boxes = {}
    for s in plan.shots:
        boxes[s.name], _ = write_shot(folder, plan, s)
        if progress is not None:
            progress.update(1)
    write_scan_metadata(root, plan, boxes)
    return plan
