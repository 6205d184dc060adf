"""Reader for BigBIRD object folders (docs/formats/bigbird.md).

One object folder holds ``calibration.h5``, Carmine RGB views ``NP{c}_{a}.jpg`` (unpadded
turntable angle ``a``), masks ``masks/NP{c}_{a}_mask.pbm`` (object = bit 1) and reference-camera
poses ``poses/NP5_{a}_pose.h5``. Camera NPc at angle a sits in the table frame (z up, metres) at
``H_table_from_NPc(a) = H_table_from_NP5(a) @ inv(H_NPc_from_NP5)``.

Images are decoded by ``loaders.jpeg`` (shared with the AVD reader).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import h5py
import numpy as np

from loaders.errors import BadInputError, SkipLog
from loaders.files import checked_file
from loaders.jpeg import jpeg_size, read_rgb
from loaders.pbm import read_pbm
from pipeline.infra.cache import note_read

_VIEW_RE = re.compile(r"^NP([1-5])_(0|[1-9][0-9]*)\.jpg$")  # angles are unpadded
POSE_KEY = "H_table_from_reference_camera"


# --------------------------------------------------------------------------------------------
# HDF5 helpers

def _read_h5_matrix(path: Path, key: str, shape: tuple[int, ...], root: str | Path | None = None) -> np.ndarray:
    """A float64 dataset of the given shape, finite, stored in the file itself; errors name the
    file and the key. Soft and external links, virtual datasets and external raw storage are
    refused: they would read (and make the run depend on) data the manifest does not track."""
    checked_file(path, root, "HDF5 file")
    note_read(path)
    try:
        with h5py.File(path, "r") as f:
            link = f.get(key, getlink=True)
            if link is None:
                raise BadInputError(path, f"missing HDF5 dataset '{key}'")
            if isinstance(link, h5py.ExternalLink):
                raise BadInputError(path, f"HDF5 key '{key}' is an external link to {link.filename}:{link.path}; "
                                          "only data stored in the file is read")
            if isinstance(link, h5py.SoftLink):
                raise BadInputError(path, f"HDF5 key '{key}' is a soft link to {link.path}; "
                                          "only data stored under its own name is read")
            ds = f[key]
            if not isinstance(ds, h5py.Dataset):
                raise BadInputError(path, f"HDF5 key '{key}' is a group, expected a dataset")
            if ds.is_virtual or ds.external:
                raise BadInputError(path, f"HDF5 dataset '{key}' keeps its data in other files "
                                          "(virtual or external storage); only data stored in the file is read")
            arr = np.asarray(ds[()], dtype=np.float64)
    except (OSError, KeyError, RuntimeError) as e:
        raise BadInputError(path, f"cannot read HDF5 dataset '{key}' ({e})") from None
    if arr.shape != shape:
        raise BadInputError(path, f"HDF5 dataset '{key}' has shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise BadInputError(path, f"HDF5 dataset '{key}' contains NaN or inf")
    return arr


def _check_homogeneous(m: np.ndarray, path: Path, key: str) -> np.ndarray:
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
        raise BadInputError(path, f"HDF5 dataset '{key}' is not a homogeneous transform "
                                  f"(last row {m[3].tolist()})")
    return m


# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class BigBirdView:
    object: str
    camera: int
    angle: int
    image_path: Path
    mask_path: Path


@dataclass(frozen=True)
class ViewRecord:
    """One fully read view: RGB image, object mask, object box (x0, y0, x1, y1; exclusive ends)
    and the 4x4 camera pose H_table_from_NPc(a)."""
    view: BigBirdView
    image: np.ndarray
    mask: np.ndarray
    box: tuple[int, int, int, int]
    pose: np.ndarray


def list_objects(root: str | Path) -> list[str]:
    """Sorted names of the object folders under ``root`` (those holding calibration.h5)."""
    root = Path(root)
    if not root.is_dir():
        raise BadInputError(root, "BigBIRD root folder is missing")
    return sorted(p.name for p in root.iterdir() if (p / "calibration.h5").is_file())


def uncalibrated_objects(root: str | Path) -> list[Path]:
    """calibration.h5 paths missing from folders under ``root`` that hold BigBIRD views
    (``NP{c}_{a}.jpg``): object folders that ``list_objects`` cannot use."""
    root = Path(root)
    out = []
    for p in sorted(root.iterdir()) if root.is_dir() else ():
        if p.is_dir() and not (p / "calibration.h5").is_file() and any(
                _VIEW_RE.match(q.name) for q in p.iterdir()):
            out.append(p / "calibration.h5")
    return out


def opening_px(shape: tuple[int, int]) -> int:
    """Default side of the speck-removing opening: about 0.5 % of the shorter image side, >= 3 px."""
    return max(3, int(round(min(shape) * 0.005)))


def mask_box(mask: np.ndarray, open_px: int | None = None, where: str | Path = "mask") -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), exclusive ends, of the largest 8-connected component of a bool mask after
    a square ``open_px`` opening (None: ``opening_px``; BigBIRD masks carry spurious specks).
    ``where`` names the mask in errors."""
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    if not mask.any():
        raise BadInputError(where, "mask is empty (no object pixels)")
    k = open_px if open_px is not None else opening_px(mask.shape)
    opened = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN,
                              cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    # The components within the bounding rectangle of what survived, not the whole image (a
    # BigBIRD mask is 1.3 MP, its object a tenth of it: 8 of a view's 25 ms went to the labelling).
    # The rectangle starts on even coordinates, so the labeller's 2x2 blocks and its scan order,
    # hence the labels and the first of equally large components, are those of the whole image.
    rx, ry, rw, rh = cv2.boundingRect(opened)
    if rw == 0 or rh == 0:
        raise BadInputError(where, f"mask has only specks: nothing survives a {k}x{k} opening")
    ox, oy = rx - rx % 2, ry - ry % 2
    n, _, stats, _ = cv2.connectedComponentsWithStats(opened[oy:ry + rh, ox:rx + rw], connectivity=8)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x0, y0 = ox + int(stats[best, cv2.CC_STAT_LEFT]), oy + int(stats[best, cv2.CC_STAT_TOP])
    x1 = x0 + int(stats[best, cv2.CC_STAT_WIDTH])
    y1 = y0 + int(stats[best, cv2.CC_STAT_HEIGHT])
    if x1 <= x0 or y1 <= y0:  # cannot happen for a non-empty component; guard anyway
        raise BadInputError(where, f"degenerate object box {(x0, y0, x1, y1)}")
    return x0, y0, x1, y1


class BigBirdObject:
    """One BigBIRD object folder.

    ``open_px``: side of the square opening that removes mask specks before the largest
    component is taken (None: about 0.5 % of the shorter image side, at least 3 px).
    ``root``: the dataset root every file must resolve inside (default: the folder's parent).
    """

    def __init__(self, folder: str | Path, open_px: int | None = None, root: str | Path | None = None):
        self.folder = Path(folder)
        self.name = self.folder.name
        self.root = Path(root) if root is not None else self.folder.parent
        if not self.folder.is_dir():
            raise BadInputError(self.folder, "BigBIRD object folder is missing")
        self.calibration_path = self.folder / "calibration.h5"
        if not self.calibration_path.is_file():
            raise BadInputError(self.calibration_path, "calibration file is missing")
        if open_px is not None and open_px < 1:
            raise ValueError(f"open_px must be >= 1, got {open_px}")
        self.open_px = open_px
        self._calib: dict[str, np.ndarray] = {}
        self._poses: dict[int, np.ndarray] = {}

    def __repr__(self) -> str:
        return f"BigBirdObject({str(self.folder)!r})"

    # ---- listing / reading -----------------------------------------------------------------
    def views(self, cameras=(1,)) -> list[BigBirdView]:
        """Views whose NP{c}_{a}.jpg exists, sorted by (camera, angle)."""
        cams = {int(c) for c in cameras}
        out = []
        for p in self.folder.iterdir():
            m = _VIEW_RE.match(p.name)
            if m and int(m.group(1)) in cams:
                c, a = int(m.group(1)), int(m.group(2))
                out.append(BigBirdView(self.name, c, a, p, self.folder / "masks" / f"NP{c}_{a}_mask.pbm"))
        out.sort(key=lambda v: (v.camera, v.angle))
        return out

    def read_image(self, view: BigBirdView) -> np.ndarray:
        return read_rgb(view.image_path, self.root)

    def read_mask(self, view: BigBirdView, shape: tuple[int, int] | None = None) -> np.ndarray:
        """Bool mask (True = object). ``shape`` = the image's (H, W); read from the JPEG header
        when not given. A mask whose size differs from its image is an error."""
        mask = read_pbm(view.mask_path, self.root)
        if shape is None:
            w, h = jpeg_size(view.image_path, self.root)
            shape = (h, w)
        if mask.shape != tuple(shape[:2]):
            raise BadInputError(view.mask_path, f"mask is {mask.shape[1]}x{mask.shape[0]} but its "
                                                f"image is {shape[1]}x{shape[0]}")
        return mask

    # ---- calibration and poses ---------------------------------------------------------------
    def check_calibration(self, cameras=(1,)) -> None:
        """Read the calibration every view of ``cameras`` needs, once: a missing or malformed key
        is one error for the object (naming the file and key), not one per view."""
        for c in cameras:
            key = f"H_NP{int(c)}_from_NP5"
            _check_homogeneous(self._calib_matrix(key, (4, 4)), self.calibration_path, key)

    def _calib_matrix(self, key: str, shape: tuple[int, int]) -> np.ndarray:
        if key not in self._calib:
            self._calib[key] = _read_h5_matrix(self.calibration_path, key, shape, self.root)
        return self._calib[key]

    def intrinsics(self, camera: int) -> np.ndarray:
        """NP{c}_rgb_K (3x3) for the 1280x1024 Carmine RGB image."""
        return self._calib_matrix(f"NP{int(camera)}_rgb_K", (3, 3)).copy()

    def reference_pose(self, angle: int) -> np.ndarray:
        """H_table_from_NP5(a), from poses/NP5_{a}_pose.h5."""
        a = int(angle)
        if a not in self._poses:
            path = self.folder / "poses" / f"NP5_{a}_pose.h5"
            if not path.is_file() and not path.is_symlink():
                raise BadInputError(path, f"pose file for angle {a} is missing")
            self._poses[a] = _check_homogeneous(_read_h5_matrix(path, POSE_KEY, (4, 4), self.root), path, POSE_KEY)
        return self._poses[a].copy()

    def camera_pose(self, camera: int, angle: int) -> np.ndarray:
        """4x4 H_table_from_NPc(a) = H_table_from_NP5(a) @ inv(H_NPc_from_NP5)."""
        key = f"H_NP{int(camera)}_from_NP5"
        h_c5 = _check_homogeneous(self._calib_matrix(key, (4, 4)), self.calibration_path, key)
        try:
            inv = np.linalg.inv(h_c5)
        except np.linalg.LinAlgError:
            raise BadInputError(self.calibration_path, f"HDF5 dataset '{key}' is singular") from None
        return self.reference_pose(angle) @ inv

    def camera_position(self, camera: int, angle: int) -> np.ndarray:
        """(3,) camera centre in the table frame, metres, z up."""
        return self.camera_pose(camera, angle)[:3, 3].copy()

    # ---- boxes -------------------------------------------------------------------------------
    def object_box(self, mask: np.ndarray, path: str | Path | None = None) -> tuple[int, int, int, int]:
        """``mask_box`` with this object's opening size; ``path`` only names the mask in errors."""
        return mask_box(mask, self.open_px, path if path is not None else f"{self.folder} (mask)")

    # ---- iteration -----------------------------------------------------------------------------
    def read_view(self, view: BigBirdView) -> ViewRecord:
        image = self.read_image(view)
        mask = self.read_mask(view, image.shape[:2])
        box = self.object_box(mask, view.mask_path)
        pose = self.camera_pose(view.camera, view.angle)
        return ViewRecord(view, image, mask, box, pose)

    def iter_views(self, cameras=(1,), skip: SkipLog | None = None) -> Iterator[ViewRecord]:
        """Read every view of the given cameras. A bad view raises BadInputError, or, with
        ``skip``, is counted and logged there and the iteration goes on."""
        for view in self.views(cameras):  # the caller's bar counts the views
            try:
                rec = self.read_view(view)
            except BadInputError as err:
                if skip is None:
                    raise
                skip.skip(err)
                continue
            yield rec
