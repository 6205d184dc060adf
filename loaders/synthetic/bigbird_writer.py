"""Write synthetic instances as BigBIRD object folders (docs/formats/bigbird.md §7).

``<root>/<object>/``: ``calibration.h5`` (float64 datasets for c = 1..5), ``poses/NP5_{a}_pose.h5``
(``H_table_from_reference_camera`` = Rz(a) @ H_table_from_NP5(0), ``board_frame_offset``),
``poses/turntable.h5``, ``NP{c}_{a}.jpg`` (RGB JPEG), ``masks/NP{c}_{a}_mask.pbm`` (P4, object =
bit 1, with a few spurious specks as in real masks) and, optionally, ``NP{c}_{a}.h5`` depth
(uint16, 0.1 mm, 480x640, in the IR camera).

The rig: five Carmines on an arc looking at a point above the turntable axis, NP1 lowest (a side
view), NP5 highest (near top-down), about 0.65 m away; at turntable angle 0 the arc lies on the
object's +x side, so NP1_0 sees the front. Every view is rendered from exactly the pose the
files give: ``H_table_from_NPc(a) = H_table_from_NP5(a) @ inv(H_NPc_from_NP5)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import h5py
import numpy as np

from loaders.pbm import encode_pbm
from loaders.synthetic.nuisance import RigNuisance, bounding_box, mask_errors, object_pose, sensor
from loaders.synthetic.objects import (Instance, make_instance, prism_faces, rot_z,
                                       transform_faces)
from loaders.synthetic.render import Camera, Light, Mesh, render
from pipeline.infra.cache import atomic_path, write_bytes
from pipeline.infra import seeds

CAMERAS = (1, 2, 3, 4, 5)
FULL_SIZE = (1280, 1024)            # Carmine RGB (width, height)
DEPTH_SIZE = (640, 480)
CANON_SIZE = (4272, 2848)
ELEVATION_RAD = {1: 0.15, 2: 0.45, 3: 0.75, 4: 1.05, 5: 1.35}
DISTANCE_M = {1: 0.66, 2: 0.64, 3: 0.65, 4: 0.67, 5: 0.63}
LOOK_AT = np.array([0.0, 0.0, 0.12])  # rig aim point above the turntable centre
# Per-camera Carmine RGB intrinsics at 1280x1024 (close to the audited NP3 values).
RGB_K = {c: (1081.2 + 3.1 * (c - 3), 1080.7 + 2.6 * (c - 3), 621.3 + 4.0 * (c - 3), 480.6 - 3.0 * (c - 3))
         for c in CAMERAS}
DEPTH_K = (574.8, 574.8, 319.5, 239.5)
CANON_K = (3460.0, 3460.0, 2135.5, 1423.5)
IR_OFFSET_M = (0.025, 0.0, 0.0)     # IR camera beside the RGB one (Carmine baseline)
CANON_OFFSET_M = (0.0, 0.07, 0.0)   # Canon mounted above each Carmine (camera y is down)
TURNTABLE_RADIUS_M = 0.2
LIGHT0 = np.array([1.0, 0.25, 1.3])  # from the rig side, above; turns with the cameras


def _K(fx, fy, cx, cy, sx=1.0, sy=1.0) -> np.ndarray:
    return np.array([[fx * sx, 0.0, cx * sx], [0.0, fy * sy, cy * sy], [0.0, 0.0, 1.0]])


def _translate(v) -> np.ndarray:
    H = np.eye(4)
    H[:3, 3] = v
    return H


def rz4(angle_deg: float) -> np.ndarray:
    H = np.eye(4)
    H[:3, :3] = rot_z(angle_deg)
    return H


@dataclass(frozen=True)
class Rig:
    """Calibration of the five-camera rig for a given RGB image size."""
    width: int
    height: int
    rgb_K: dict                 # c -> 3x3, for (width, height)
    H_from_NP5: dict            # c -> 4x4 H_NPc_from_NP5
    H_ir_from_NP5: dict         # c -> 4x4 H_NPc_ir_from_NP5
    H_canon_from_NP5: dict      # c -> 4x4 H_Nc_from_NP5
    H_table_from_NP5_0: np.ndarray

    def reference_pose(self, angle: int) -> np.ndarray:
        """H_table_from_NP5(a) = Rz(a) @ H_table_from_NP5(0): the cameras turn about table z."""
        return rz4(angle) @ self.H_table_from_NP5_0

    def camera_pose(self, camera: int, angle: int) -> np.ndarray:
        """H_table_from_NPc(a), computed exactly as a reader computes it from the files."""
        return self.reference_pose(angle) @ np.linalg.inv(self.H_from_NP5[camera])

    def camera(self, camera: int, angle: int) -> Camera:
        return Camera.from_pose(self.camera_pose(camera, angle), self.rgb_K[camera], self.width, self.height)

    def depth_camera(self, camera: int, angle: int) -> Camera:
        H = self.reference_pose(angle) @ np.linalg.inv(self.H_ir_from_NP5[camera])
        return Camera.from_pose(H, _K(*DEPTH_K), *DEPTH_SIZE)

    def light(self, angle: int) -> Light:
        return Light(tuple(rot_z(angle) @ LIGHT0), (1.0, 1.0, 1.0), ambient=0.72, diffuse=0.38)


@lru_cache(maxsize=8)
def make_rig(width: int = FULL_SIZE[0], height: int = FULL_SIZE[1]) -> Rig:
    sx, sy = width / FULL_SIZE[0], height / FULL_SIZE[1]
    poses0 = {}
    for c in CAMERAS:
        el, dist = ELEVATION_RAD[c], DISTANCE_M[c]
        eye = LOOK_AT + dist * np.array([np.cos(el), 0.0, np.sin(el)])
        poses0[c] = Camera.look_at(eye, LOOK_AT, np.eye(3), 1, 1).pose()  # H_table_from_NPc(0)
    H5 = poses0[5]
    H_from = {c: np.linalg.inv(poses0[c]) @ H5 for c in CAMERAS}
    H_from[5] = np.eye(4)  # exactly identity, as in the real files
    H_ir = {c: _translate(-np.asarray(IR_OFFSET_M)) @ H_from[c] for c in CAMERAS}
    H_canon = {c: _translate(-np.asarray(CANON_OFFSET_M)) @ H_from[c] for c in CAMERAS}
    return Rig(width, height, {c: _K(*RGB_K[c], sx, sy) for c in CAMERAS}, H_from, H_ir, H_canon, H5)


def calibration_datasets(rig: Rig) -> dict[str, np.ndarray]:
    """Every calibration.h5 dataset (float64), keyed as in the real files."""
    out: dict[str, np.ndarray] = {}
    for c in CAMERAS:
        out[f"H_NP{c}_from_NP5"] = rig.H_from_NP5[c]
        out[f"H_NP{c}_ir_from_NP5"] = rig.H_ir_from_NP5[c]
        out[f"H_N{c}_from_NP5"] = rig.H_canon_from_NP5[c]
        out[f"NP{c}_rgb_K"] = rig.rgb_K[c]
        out[f"NP{c}_depth_K"] = _K(*DEPTH_K)
        out[f"NP{c}_ir_K"] = _K(*DEPTH_K)
        out[f"N{c}_rgb_K"] = _K(*CANON_K)
        # The renders have no lens distortion, so the coefficients are zero (a valid calibration).
        out[f"NP{c}_rgb_d"] = np.zeros(5)
        out[f"NP{c}_ir_d"] = np.zeros(5)
        out[f"N{c}_rgb_d"] = np.zeros(5)
        out[f"NP{c}_ir_depth_scale"] = np.array([1.0])
        out[f"NP{c}_ir_depth_bias"] = np.array([0.0])
        out[f"NP{c}_depth_scale"] = np.array([1.0])
        out[f"NP{c}_depth_bias"] = np.array([0.0])
    return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}


def write_h5(path: Path, datasets: dict[str, np.ndarray]) -> None:
    """An HDF5 file of root datasets, written atomically."""
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            for k, v in datasets.items():
                f.create_dataset(k, data=v)


def angles(step_deg: int) -> list[int]:
    return list(range(0, 360, int(step_deg)))


def write_object_metadata(folder: Path, rig: Rig, step_deg: int) -> None:
    """calibration.h5 and poses/ for one object folder."""
    folder.mkdir(parents=True, exist_ok=True)
    write_h5(folder / "calibration.h5", calibration_datasets(rig))
    for a in angles(step_deg):
        write_h5(folder / "poses" / f"NP5_{a}_pose.h5",
                 {"H_table_from_reference_camera": rig.reference_pose(a),
                  # Unused by every public reader; its meaning is unverified (formats §4).
                  "board_frame_offset": np.zeros(3)})
    write_h5(folder / "poses" / "turntable.h5", {"center": np.zeros(3), "normal": np.array([0.0, 0.0, 1.0])})


@lru_cache(maxsize=4)
def _background(width: int, height: int) -> np.ndarray:
    """Plain bright rig backdrop: a soft vertical gradient."""
    g = np.linspace(238, 214, height, dtype=np.float32)[:, None, None]
    tint = np.array([1.0, 1.0, 0.985], np.float32)
    img = np.broadcast_to(g * tint, (height, width, 3))
    out = np.ascontiguousarray(np.clip(img, 0, 255).astype(np.uint8))
    out.setflags(write=False)
    return out


@lru_cache(maxsize=2)
def _turntable() -> Mesh:
    th = np.linspace(0, 2 * np.pi, 33)[:-1]
    foot = TURNTABLE_RADIUS_M * np.stack([np.cos(th), np.sin(th)], 1)
    # Drawn as a shell (first, no occlusion test): it lies below z = 0 and every camera is above
    # that plane, so it can never hide the object; skipping its 1/z test saves a third of a view.
    return Mesh(tuple(prism_faces(foot, -0.02, 0.0, side_color=(0.25, 0.25, 0.26), top_color=(0.42, 0.42, 0.43))),
                0, shell=True)


def object_meshes(instance: Instance, pose: tuple | None = None) -> list[Mesh]:
    """The instance's parts, optionally placed by (R, t) on the table (decentring, wobble)."""
    if pose is None:
        return [Mesh(p.faces, instance.instance_id) for p in instance.parts]
    R, t = pose
    return [Mesh(transform_faces(p.faces, R, t), instance.instance_id) for p in instance.parts]


def add_specks(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A few isolated specks away from the object, small enough for a mask cleanup to remove
    (real BigBIRD masks carry such noise; readers open the mask and keep the largest part)."""
    h, w = mask.shape
    k = max(3, int(round(min(h, w) * 0.005)))
    side_max = max(1, k - 2)
    out = mask.copy()
    for _ in range(int(rng.integers(2, 7))):
        s = int(rng.integers(1, side_max + 1))
        y, x = int(rng.integers(0, h - s)), int(rng.integers(0, w - s))
        if not mask[max(0, y - 4):y + s + 4, max(0, x - 4):x + s + 4].any():
            out[y:y + s, x:x + s] = True
    return out


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV only fails on invalid input
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def render_view(instance: Instance, rig: Rig, camera: int, angle: int, pose: tuple | None = None):
    """RGB, object mask (no specks, no sensor effects) for one view; ``pose`` places the object."""
    cam = rig.camera(camera, angle)
    res = render(cam, [_turntable(), *object_meshes(instance, pose)], rig.light(angle),
                 _background(rig.width, rig.height))
    return res.rgb, res.ids == instance.instance_id


def write_view(folder: Path, instance: Instance, rig: Rig, camera: int, angle: int, *, seed: int,
               nuisance: RigNuisance, write_depth: bool) -> dict:
    """Render and write one view's files; returns what it wrote (bytes, object box)."""
    pose = object_pose(nuisance, seed, instance.name, angle)
    rgb, mask = render_view(instance, rig, camera, angle, pose)
    if not mask.any():
        raise RuntimeError(f"{folder.name} NP{camera}_{angle}: the object is not in view (rig misconfigured)")
    rng = seeds.stream(seed, "bigbird-view", instance.name, camera, angle)
    jpg = encode_jpeg(sensor(rgb, nuisance, seed, rng), nuisance.quality)
    written = mask_errors(mask, nuisance.mask_error_px, rng)
    pbm = encode_pbm(add_specks(written, rng))
    write_bytes(folder / f"NP{camera}_{angle}.jpg", jpg)
    write_bytes(folder / "masks" / f"NP{camera}_{angle}_mask.pbm", pbm)
    nbytes = len(jpg) + len(pbm)
    if write_depth:
        d = render(rig.depth_camera(camera, angle), [_turntable(), *object_meshes(instance, pose)],
                   rig.light(angle), depth_only=True).depth
        raw = np.clip(np.round(d * 1e4), 0, 65535).astype(np.uint16)  # 0.1 mm units, 0 = invalid
        write_h5(folder / f"NP{camera}_{angle}.h5", {"depth": raw})
        nbytes += raw.nbytes
    x, y, w, h = bounding_box(mask)
    return {"camera": camera, "angle": angle, "bytes": nbytes, "box": [x, y, x + w, y + h]}


def write_bigbird_object(root: str | Path, name: str, cfg, seed: int, progress=None) -> list[dict]:
    """Write one complete object folder ``<root>/<name>/`` serially.

    ``cfg`` is the ``data.synthetic`` config section (cameras, angle step, image size, the
    ``bigbird_*`` nuisance knobs, depth). Each view's randomness comes from (seed, object, camera,
    angle), so the stage can render views in any order or process and get the same files.
    """
    folder = Path(root) / name
    rig = make_rig(cfg.bigbird_width, cfg.bigbird_height)
    write_object_metadata(folder, rig, cfg.angle_step_deg)
    inst = make_instance(name, seed)
    nz = RigNuisance.from_config(cfg)
    out = []
    for c in cfg.bigbird_cameras:
        for a in angles(cfg.angle_step_deg):
            out.append(write_view(folder, inst, rig, c, a, seed=seed, nuisance=nz, write_depth=cfg.write_depth))
            if progress is not None:
                progress.update(1)
    return out
