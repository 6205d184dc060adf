"""Tiny hand-made BigBIRD object folders and AVD scans for the reader tests.

Independent of loaders/synthetic on purpose: these writers encode known ground truth (camera
positions, headings, boxes) directly in the on-disk formats of docs/formats/bigbird.md and avd.md, so
the readers can be checked against it.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import cv2
import h5py
import numpy as np
import scipy.io
from scipy.spatial.transform import Rotation

from loaders.pbm import encode_pbm

# ---------------------------------------------------------------------------------------------
# shared


def write_jpeg(path: Path, rgb: np.ndarray, quality: int = 85) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    path.write_bytes(buf.tobytes())


def rot_z(deg: float) -> np.ndarray:
    a = math.radians(deg)
    H = np.eye(4)
    H[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return H


def look_at(cam: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """H_world_from_cam for a camera at ``cam`` looking at ``target`` (x right, y down, z fwd)."""
    z = np.asarray(target, float) - np.asarray(cam, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    H = np.eye(4)
    H[:3, :3] = np.stack([x, y, z], axis=1)
    H[:3, 3] = cam
    return H


# ---------------------------------------------------------------------------------------------
# BigBIRD

# Camera centres at turntable angle 0 in the table frame (z up, metres): NP1 low, NP5 high.
BB_CAMERA_POS = {1: np.array([0.62, 0.05, 0.12]), 2: np.array([0.58, 0.0, 0.25]),
                 3: np.array([0.50, -0.02, 0.38]), 4: np.array([0.40, 0.03, 0.50]),
                 5: np.array([0.25, 0.0, 0.62])}
BB_TARGET = np.array([0.0, 0.0, 0.08])


def bb_box(camera: int, angle: int) -> tuple[int, int, int, int]:
    """Object rectangle (x0, y0, x1, y1, exclusive) drawn for one view of a 64x48 image."""
    k = (angle // 3) % 5
    return 12 + 2 * k, 8 + camera, 36 + 3 * k, 30 + camera + k


def make_bigbird_object(root: Path, name: str = "aunt_jemima_original_syrup",
                        angles=(0, 3, 6, 9, 12), cameras=(1, 3), size=(64, 48)) -> dict:
    """Write one object folder; return the ground truth used to make it."""
    folder = Path(root) / name
    (folder / "masks").mkdir(parents=True, exist_ok=True)
    (folder / "poses").mkdir(parents=True, exist_ok=True)
    T = {c: look_at(p, BB_TARGET) for c, p in BB_CAMERA_POS.items()}  # H_table_from_NPc(0)
    H_c_from_5 = {c: np.linalg.inv(T[c]) @ T[5] for c in T}
    K = {c: np.array([[80.0 + c, 0, 31.5 + 0.1 * c], [0, 81.0 + c, 23.5 - 0.1 * c], [0, 0, 1]]) for c in T}
    with h5py.File(folder / "calibration.h5", "w") as f:
        for c in range(1, 6):
            f[f"H_NP{c}_from_NP5"] = H_c_from_5[c]
            f[f"H_NP{c}_ir_from_NP5"] = H_c_from_5[c] @ rot_z(0.5)
            f[f"H_N{c}_from_NP5"] = H_c_from_5[c] @ rot_z(-0.5)
            f[f"NP{c}_rgb_K"] = K[c]
            for k in ("NP{c}_depth_K", "NP{c}_ir_K", "N{c}_rgb_K"):
                f[k.format(c=c)] = K[c] * np.array([[0.5, 1, 0.5], [1, 0.5, 0.5], [1, 1, 1]])
            f[f"NP{c}_rgb_d"] = np.zeros(5)
            f[f"NP{c}_ir_d"] = np.zeros(5)
            f[f"NP{c}_ir_depth_scale"] = np.array([1.0])
            f[f"NP{c}_ir_depth_bias"] = np.array([0.0])
    poses = {}
    for a in angles:
        poses[a] = rot_z(a) @ T[5]  # the turntable turns the rig about table z
        with h5py.File(folder / "poses" / f"NP5_{a}_pose.h5", "w") as f:
            f["H_table_from_reference_camera"] = poses[a]
            f["board_frame_offset"] = np.array([0.01, -0.02, 0.0])
    w, h = size
    rng = np.random.default_rng(0)
    boxes = {}
    for c in cameras:
        for a in angles:
            x0, y0, x1, y1 = boxes[(c, a)] = bb_box(c, a)
            mask = np.zeros((h, w), bool)
            mask[y0:y1, x0:x1] = True
            mask[2:4, 58:60] = True      # a 2x2 speck: removed by the opening
            mask[40:45, 2:7] = True      # a 5x5 blob: survives the opening, but is smaller
            (folder / "masks" / f"NP{c}_{a}_mask.pbm").write_bytes(encode_pbm(mask))
            img = rng.integers(90, 110, size=(h, w, 3), dtype=np.uint8)
            img[mask] = (200, 40, 30)
            write_jpeg(folder / f"NP{c}_{a}.jpg", img)
    return {"folder": folder, "T": T, "H_c_from_5": H_c_from_5, "poses": poses, "K": K,
            "boxes": boxes, "angles": tuple(angles), "cameras": tuple(cameras)}


# ---------------------------------------------------------------------------------------------
# AVD

INSTANCE_MAP_LINES = [
    "background 0", "advil_liqui_gels 1", "aunt_jemima_original_syrup 2", "bumblebee_albacore 3",
    "cholula_chipotle_hot_sauce 4", "coca_cola_glass_bottle 5", "crest_complete_minty_fresh 6",
    "crystal_hot_sauce 7",
]
AVD_FIELDS = ("image_name", "t", "R", "world_pos", "direction", "quat", "scaled_world_pos",
              "image_id", "camera_id", "cluster_id", "rotate_cw", "rotate_ccw",
              "translate_forward", "translate_backward", "translate_right", "translate_left")

# (point, orientation) -> boxes [x0, y0, x1, y1, id, difficulty]; sizes pick difficulties 1..5.
AVD_BOXES = {
    (0, 0): [[10, 20, 330, 130, 2, 1]],                       # 320x110 -> 1
    (0, 1): [[100, 50, 350, 130, 2, 2], [0, 0, 20, 10, 7, 5]],  # 250x80 -> 2 ; 20x10 -> 5
    (0, 2): [[100, 50, 350, 110, 2, 3]],                      # 250x60 -> 3
    (1, 0): [[400, 200, 460, 240, 2, 4]],                     # 60x40 -> 4
    (1, 5): [[200, 100, 280, 200, 7, 3]],                     # 80x100 -> 3
}


def avd_name(scan: str, index: int) -> str:
    kind, scene, num = scan.split("_")
    code = {"Home": "0", "Office": "1"}[kind]  # AVD's scene-type digit
    return f"{code}{scene}{num}{index:06d}0101.jpg"


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def make_avd_scan(root: Path, scan: str = "Home_001_1", points=((0.0, 0.0), (0.3, 0.0)),
                  phi0_deg: float = 10.0, height_m: float = 0.9, scale: float = 250.0,
                  size=(480, 270), interpolated=(1, 5, 14, 20), boxes=None,
                  recon_seed: int | None = None, recon_scale: float = 1.0,
                  struct_edit: Callable[[list[dict]], None] | None = None,
                  annotation_edit: Callable[[dict], None] | None = None,
                  cameras_txt: str | None = None) -> dict:
    """Write ``root/instance_id_map.txt`` and ``root/<scan>/``: len(points) grid points x 12
    orientations. Ground truth: camera j of point k at ``points[k]`` (metres) heading
    ``phi0 + 30°·j`` (ccw = index+1). Recon coords follow the writer convention (recon x =
    ground x, recon y = -height, recon z = ground y, ×1000/scale), then, with ``recon_seed``,
    a random rotation, scale ``recon_scale`` and offset are applied to the whole reconstruction
    (``scale`` is divided by ``recon_scale`` so millimetres stay right). ``interpolated`` lists
    0-based image indices left unregistered (empty R, t, quat)."""
    root = Path(root)
    folder = root / scan
    (folder / "jpg_rgb").mkdir(parents=True, exist_ok=True)
    (root / "instance_id_map.txt").write_text("\n".join(INSTANCE_MAP_LINES) + "\n")
    (folder / "present_instance_names.txt").write_text("aunt_jemima_original_syrup\ncrystal_hot_sauce\n")
    boxes = AVD_BOXES if boxes is None else boxes
    if recon_seed is None:
        Q, s_r, b = np.eye(3), 1.0, np.zeros(3)
    else:
        rng = np.random.default_rng(recon_seed)
        Q, s_r, b = _random_rotation(rng), float(recon_scale), rng.normal(scale=5.0, size=3)
    file_scale = scale / s_r
    w, h = size
    names, truth_pos, truth_head, structs, ann = [], {}, {}, [], {}
    n = 12 * len(points)
    for k, (x, y) in enumerate(points):
        for j in range(12):
            idx = 12 * k + j
            name = avd_name(scan, idx + 1)
            names.append(name)
            phi = math.radians(phi0_deg + 30.0 * j)
            truth_pos[name] = np.array([x, y])
            truth_head[name] = phi
            X = np.array([x, -height_m, y]) * 1000.0 / scale      # writer convention
            d = np.array([math.cos(phi), 0.0, math.sin(phi)])
            Xr = s_r * Q @ X + b
            yc = Q @ np.array([0.0, 1.0, 0.0])  # image-down = recon +y (= -height)
            zc = Q @ d
            xc = np.cross(yc, zc)
            R = np.stack([xc, yc, zc])           # world->camera rows: camera x, y, z axes
            t = -R @ Xr
            registered = idx not in interpolated
            qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
            ring = lambda jj: avd_name(scan, 12 * k + (jj % 12) + 1)  # noqa: E731
            structs.append({
                "image_name": name,
                "t": t.reshape(3, 1) if registered else np.zeros((0, 0)),
                "R": R if registered else np.zeros((0, 0)),
                "world_pos": Xr.reshape(3, 1),
                "direction": zc.reshape(3, 1),
                "quat": np.array([[qw], [qx], [qy], [qz]]) if registered else np.zeros((0, 0)),
                "scaled_world_pos": (Xr * file_scale).reshape(3, 1),
                "image_id": str(idx + 1) if registered else "",
                "camera_id": "1" if registered else "",
                "cluster_id": float(k + 1),
                "rotate_cw": ring(j - 1), "rotate_ccw": ring(j + 1),
                "translate_forward": -1.0, "translate_backward": -1.0,
                "translate_right": -1.0, "translate_left": -1.0,
            })
            fwd = avd_name(scan, 12 * (k + 1) + j + 1) if (j == 0 and k + 1 < len(points)) else ""
            bwd = avd_name(scan, 12 * (k - 1) + j + 1) if (j == 0 and k > 0) else ""
            ann[name] = {"bounding_boxes": [list(bb) for bb in boxes.get((k, j), [])],
                         "rotate_ccw": ring(j + 1), "rotate_cw": ring(j - 1),
                         "forward": fwd, "backward": bwd, "left": "", "right": ""}
            img = np.full((h, w, 3), (60 + 7 * j, 120, 90 + 40 * k), np.uint8)
            write_jpeg(folder / "jpg_rgb" / name, img)
    if struct_edit is not None:
        struct_edit(structs)
    if annotation_edit is not None:
        annotation_edit(ann)
    arr = np.zeros((1, len(structs)), dtype=[(f, "O") for f in AVD_FIELDS])
    for i, s in enumerate(sorted(structs, key=lambda s: s["image_name"])):
        for f in AVD_FIELDS:
            arr[0, i][f] = s[f]
    scipy.io.savemat(folder / "image_structs.mat", {"image_structs": arr, "scale": np.array([[file_scale]])})
    (folder / "annotations.json").write_text(json.dumps(ann, indent=1))
    if cameras_txt is not None:
        (folder / "cameras.txt").write_text(cameras_txt)
    return {"root": root, "scan": scan, "folder": folder, "names": names, "n": n,
            "position": truth_pos, "heading": truth_head, "boxes": boxes,
            "interpolated": {names[i] for i in interpolated if i < n}, "size": size}
