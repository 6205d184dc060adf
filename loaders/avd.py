"""Reader for Active Vision Dataset scans (docs/formats/avd.md).

``<root>/instance_id_map.txt`` maps instance names to ids; ``<root>/<scan>/`` holds ``jpg_rgb/``,
``annotations.json`` (boxes + move pointers), ``image_structs.mat`` (COLMAP poses, ``scale``
to millimetres) and ``present_instance_names.txt``.

Ground frame (docs/design.md §4): camera centre ``c = -Rᵀt`` (registered) or ``world_pos``
(interpolated); ``up = -mean(Rᵀ[0,1,0])`` over registered images (COLMAP's image-down axis);
``e1`` = recon x projected onto the plane ⟂ up, ``e2 = up × e1`` so ``e1 × e2 = up`` (right-handed
seen from above). position = (c·e1, c·e2)·scale/1000 m; heading = atan2(d·e2, d·e1) with
d = Rᵀ[0,0,1] (registered) or ``direction`` (interpolated).
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.io

from loaders.avd_boxes import AVDBox, BoxNotes, difficulty, parse_box  # noqa: F401 - AVDBox, difficulty: public here
from loaders.jpeg import jpeg_size, read_rgb
from loaders.errors import BadInputError, SkipLog
from loaders.files import checked_file, plain_name, read_checked
from pipeline.scene.viewpoints import scan_grid_points
from pipeline.infra.cache import note_read
from pipeline.infra.progress import bar

log = logging.getLogger("viewfuse.loaders")

STRUCT_FIELDS = ("image_name", "t", "R", "world_pos", "direction", "quat", "scaled_world_pos",
                 "image_id", "camera_id", "cluster_id", "rotate_cw", "rotate_ccw",
                 "translate_forward", "translate_backward", "translate_right", "translate_left")
_NEIGHBOUR_FIELDS = STRUCT_FIELDS[10:]
_STRING_FIELDS = ("image_name", "image_id", "camera_id") + _NEIGHBOUR_FIELDS
MOVES = ("forward", "backward", "left", "right", "rotate_cw", "rotate_ccw")

# The authors' Kinect-1 colour calibration at 1920x1080 (docs/formats/avd.md §7).
KINECT_SIZE = (1920, 1080)
KINECT_K = np.array([[1070.0016, 0.0, 927.2688],
                     [0.0, 1069.1226, 545.7610],
                     [0.0, 0.0, 1.0]])

@dataclass
class AVDImage:
    name: str
    path: Path
    boxes: list[AVDBox]
    moves: dict[str, str]
    position: np.ndarray   # (2,) metres, right-handed ground frame seen from above
    heading: float         # radians, optical-axis direction in that ground frame
    registered: bool       # False for interpolated entries (empty R, t, quat)
    struct: dict = field(repr=False)  # all 16 image_structs fields (empty arrays where missing)


def read_instance_map(path: str | Path, root: str | Path | None = None) -> dict[str, int]:
    """name -> id from an AVD instance_id_map.txt (``name id`` per line)."""
    path = Path(path)
    try:
        text = read_checked(path, root, "instance id map").decode("utf-8")
    except UnicodeDecodeError as e:
        raise BadInputError(path, f"not a text file ({e})") from None
    note_read(path)
    out: dict[str, int] = {}
    seen: dict[int, str] = {}
    for no, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks:
            continue
        if len(toks) != 2:
            raise BadInputError(path, f"line {no}: expected 'name id', got {line!r}")
        name, sid = toks
        plain_name(name, path, f"line {no}: instance name")
        try:
            iid = int(sid)
        except ValueError:
            raise BadInputError(path, f"line {no}: id {sid!r} is not an integer") from None
        if name in out:
            raise BadInputError(path, f"line {no}: instance {name!r} listed twice")
        if iid in seen:
            raise BadInputError(path, f"line {no}: id {iid} used by both {seen[iid]!r} and {name!r}")
        out[name] = iid
        seen[iid] = name
    if not out:
        raise BadInputError(path, "instance id map is empty")
    return out


# --------------------------------------------------------------------------------------------
# image_structs.mat

def _cell(value, fname: str):
    """One struct field as loaded by scipy (default args) -> str for text fields ('' = none,
    also for the -1 'no neighbour' default), float64 array otherwise; empty -> (0,0) array."""
    a = np.asarray(value)
    if a.dtype.kind == "U":
        return "".join(str(s) for s in a.ravel())
    if a.size == 0:
        return "" if fname in _STRING_FIELDS else np.zeros((0, 0))
    if a.dtype.kind in "biuf":
        a = a.astype(np.float64)
        if fname in _NEIGHBOUR_FIELDS and a.size == 1 and a.ravel()[0] == -1:
            return ""
        if fname in ("image_id", "camera_id") and a.size == 1:
            return str(int(a.ravel()[0])) if float(a.ravel()[0]).is_integer() else str(a.ravel()[0])
        return a
    return a


def _read_structs(path: Path, root: Path | None = None) -> tuple[float, dict[str, dict]]:
    checked_file(path, root, "image_structs.mat")
    note_read(path)
    try:
        m = scipy.io.loadmat(path)
    except Exception as e:  # scipy raises several types on malformed files
        raise BadInputError(path, f"cannot read MATLAB file ({type(e).__name__}: {e})") from None
    for key in ("image_structs", "scale"):
        if key not in m:
            raise BadInputError(path, f"missing variable '{key}'")
    scale_arr = np.asarray(m["scale"], dtype=np.float64)
    if scale_arr.size != 1:
        raise BadInputError(path, f"'scale' has shape {scale_arr.shape}, expected 1x1")
    scale = float(scale_arr.ravel()[0])
    if not (math.isfinite(scale) and scale > 0):
        raise BadInputError(path, f"'scale' is {scale}, expected a positive finite number")
    arr = m["image_structs"]
    names = arr.dtype.names or ()
    for req in ("image_name", "world_pos", "direction"):
        if req not in names:
            raise BadInputError(path, f"image_structs has no field '{req}'")
    structs: dict[str, dict] = {}
    for el in arr.ravel():
        s = {f: (_cell(el[f], f) if f in names else ("" if f in _STRING_FIELDS else np.zeros((0, 0))))
             for f in STRUCT_FIELDS}
        if not s["image_name"]:
            raise BadInputError(path, "an image_structs entry has an empty image_name")
        if s["image_name"] in structs:
            raise BadInputError(path, f"image_structs lists {s['image_name']!r} twice")
        structs[s["image_name"]] = s
    return scale, structs


def _vec(s: dict, key: str, n: int, path: Path, name: str) -> np.ndarray:
    v = s[key]
    if not isinstance(v, np.ndarray) or v.size != n:
        raise BadInputError(path, f"image {name}: field '{key}' has "
                                  f"{getattr(v, 'size', 0)} values, expected {n}")
    v = v.reshape(-1).astype(np.float64)
    if not np.all(np.isfinite(v)):
        raise BadInputError(path, f"image {name}: field '{key}' contains NaN or inf")
    return v


def _camera(s: dict, path: Path, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(centre, direction, R or None) in recon coordinates for one struct."""
    R, t = s["R"], s["t"]
    registered = isinstance(R, np.ndarray) and isinstance(t, np.ndarray) and R.size > 0 and t.size > 0
    if registered:
        R = _vec(s, "R", 9, path, name).reshape(3, 3)
        t = _vec(s, "t", 3, path, name)
        return -R.T @ t, R[2].copy(), R  # c = -Rᵀt; optical axis Rᵀ[0,0,1] = third row of R
    c = _vec(s, "world_pos", 3, path, name)
    d = _vec(s, "direction", 3, path, name)
    return c, d, None


def ground_frame(down_axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(up, axes) from the registered cameras' image-down axes Rᵀ[0,1,0] (rows of down_axes).
    axes = [e1, e2] with e1 = recon x projected ⟂ up and e2 = up × e1 (e1 × e2 = up)."""
    up = -np.mean(down_axes, axis=0)
    nrm = np.linalg.norm(up)
    if not nrm > 1e-9:
        raise ValueError("camera image-down axes cancel out: no up direction")
    up = up / nrm
    for ref in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])):
        e1 = ref - (ref @ up) * up
        if np.linalg.norm(e1) > 1e-3:  # recon x nearly vertical: fall back to recon z
            break
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return up, np.stack([e1, e2])


# --------------------------------------------------------------------------------------------

class AVDScan:
    """One AVD scan: images (sorted by name) with boxes, move pointers and ground-frame poses.

    With ``skip`` (a SkipLog), bad entries that should not stop a run are counted and logged
    there instead of raising: annotation entries naming images not in jpg_rgb/, JPGs without
    an annotation or image_structs entry or with an unreadable header, images whose pose is
    NaN (dropped), and single bad boxes (degenerate, mostly outside the image, unknown instance).
    Boxes with difficulty 0 (not assigned) or overshooting the image edge are kept, repaired
    (``loaders.avd_boxes``) and counted in ``box_notes``.

    ``frames=False`` is the metadata-only mode, for a copy without ``jpg_rgb/`` (the real
    metadata in ``../shared/realdata/avd``): the images are the annotations.json entries, each
    ``image_size`` pixels (default the published 1920x1080, docs/formats/avd.md §2), and
    ``read_image`` refuses. Poses, boxes and the move graph read exactly as with frames.
    """

    def __init__(self, root: str | Path, scan: str, skip: SkipLog | None = None, *, frames: bool = True,
                 image_size: tuple[int, int] = KINECT_SIZE):
        self.root = Path(root)
        self.scan = plain_name(scan, self.root, "AVD scan folder")
        self.folder = self.root / scan
        self.skip = skip
        self.frames = bool(frames)
        self.box_notes = BoxNotes()
        if not self.folder.is_dir():
            raise BadInputError(self.folder, "AVD scan folder is missing")
        self.instance_ids = read_instance_map(self.root / "instance_id_map.txt", self.root)
        self.instance_names = {i: n for n, i in self.instance_ids.items()}
        jpg_dir = self.folder / "jpg_rgb"
        if self.frames and not jpg_dir.is_dir():
            raise BadInputError(jpg_dir, "jpg_rgb/ folder is missing (a metadata-only copy reads with frames=False)")
        self._image_size: tuple[int, int] | None = None if self.frames else (int(image_size[0]), int(image_size[1]))
        ann_path = self.folder / "annotations.json"
        annotations = self._read_annotations(ann_path)
        self.structs_path = self.folder / "image_structs.mat"
        self.scale, structs = _read_structs(self.structs_path, self.root)
        self.present_instances = self._read_present(self.folder / "present_instance_names.txt", annotations)
        if self.frames:
            files = {p.name: p for p in jpg_dir.iterdir() if p.suffix.lower() == ".jpg"}
        else:
            files = {name: jpg_dir / name for name in annotations}

        for name in sorted(set(annotations) - set(files)):
            self._bad(BadInputError(ann_path, f"annotation names image {name!r}, which is not in jpg_rgb/"))

        # Ground frame from every registered camera in the file.
        cams: dict[str, tuple] = {}
        for name, s in structs.items():
            try:
                cams[name] = _camera(s, self.structs_path, name)
            except BadInputError as err:
                cams[name] = err
        downs = [c[2][1] for c in cams.values() if isinstance(c, tuple) and c[2] is not None]
        if not downs:
            raise BadInputError(self.structs_path, "no registered image (all R, t empty): "
                                                   "cannot estimate the up direction")
        try:
            self.up, self.axes = ground_frame(np.array(downs))
        except ValueError as e:
            raise BadInputError(self.structs_path, str(e)) from None
        mm_to_m = self.scale / 1000.0

        self.images: dict[str, AVDImage] = {}
        for name in bar(sorted(files), desc=f"read AVD scan {scan}", unit="image", leave=False):
            path = files[name]
            if name not in annotations:
                self._bad(BadInputError(ann_path, f"no annotation entry for image {name!r}"))
                continue
            if name not in structs:
                self._bad(BadInputError(self.structs_path, f"no image_structs entry for image {name!r}"))
                continue
            cam = cams[name]
            if isinstance(cam, BadInputError):
                self._bad(cam)
                continue
            c, d, R = cam
            pos = (self.axes @ c) * mm_to_m
            dg = self.axes @ d
            if not np.linalg.norm(dg) > 1e-9:
                self._bad(BadInputError(self.structs_path, f"image {name}: viewing direction is vertical"))
                continue
            entry = annotations[name]
            try:
                boxes = self._boxes(entry, name, path, ann_path)
            except BadInputError as err:
                self._bad(err)
                continue
            moves = {k: entry.get(k, "") or "" for k in MOVES}
            self.images[name] = AVDImage(name=name, path=path, boxes=boxes, moves=moves,
                                         position=pos, heading=float(math.atan2(dg[1], dg[0])),
                                         registered=R is not None, struct=structs[name])
        if self.box_notes.unassigned or self.box_notes.clipped:
            log.info("%s: kept %d box(es) with difficulty 0 (size rule's level assigned) and %d clipped to the "
                     "image edge", ann_path, self.box_notes.unassigned, self.box_notes.clipped)

    # ---- parsing helpers -----------------------------------------------------------------------
    def _bad(self, err: BadInputError) -> None:
        if self.skip is None:
            raise err
        self.skip.skip(err)

    def _read_annotations(self, path: Path) -> dict:
        try:
            data = json.loads(read_checked(path, self.root, "annotations.json").decode("utf-8"))
            note_read(path)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise BadInputError(path, f"not valid JSON ({e})") from None
        if not isinstance(data, dict):
            raise BadInputError(path, f"expected a JSON object keyed by image name, got {type(data).__name__}")
        # Image keys become file paths (frames=False) and are written by the real-imagery writer.
        for name in list(data):
            try:
                plain_name(name, path, "image key")
            except BadInputError as err:
                self._bad(err)
                del data[name]
        for name, entry in data.items():
            if not isinstance(entry, dict) or "bounding_boxes" not in entry:
                raise BadInputError(path, f"entry {name!r} has no 'bounding_boxes' list")
            for k in MOVES:
                if not isinstance(entry.get(k, ""), str):
                    raise BadInputError(path, f"entry {name!r}: move {k!r} is not a string")
        return data

    def _read_present(self, path: Path, annotations: dict) -> list[str]:
        if not path.exists() and not path.is_symlink():
            # Optional for us: fall back to the instances that carry boxes, and say so.
            ids = sorted({int(b[4]) for e in annotations.values() for b in e["bounding_boxes"]
                          if len(b) == 6 and int(b[4]) in self.instance_names})
            log.warning("%s: missing; using the %d instances seen in annotations.json", path, len(ids))
            return [self.instance_names[i] for i in ids]
        try:
            text = read_checked(path, self.root, "present_instance_names.txt").decode("utf-8")
        except UnicodeDecodeError as e:
            raise BadInputError(path, f"not a text file ({e})") from None
        note_read(path)
        names = [ln.strip() for ln in text.splitlines() if ln.strip()]
        for n in names:
            if n not in self.instance_ids:
                raise BadInputError(path, f"instance {n!r} is not in {self.root / 'instance_id_map.txt'}")
        return names

    def _boxes(self, entry: dict, name: str, img_path: Path, ann_path: Path) -> list[AVDBox]:
        raw = entry["bounding_boxes"]
        if not isinstance(raw, list):
            raise BadInputError(ann_path, f"image {name}: 'bounding_boxes' is not a list")
        if not raw:
            return []
        w, h = jpeg_size(img_path, self.root) if self.frames else self._image_size
        out = []
        for b in raw:
            try:
                out.append(parse_box(b, name, w, h, ann_path, self.instance_names, self.box_notes))
            except BadInputError as err:
                self._bad(err)  # one bad box: skip just that box when skipping
        return out

    # ---- public API ----------------------------------------------------------------------------
    def __repr__(self) -> str:
        return f"AVDScan({str(self.root)!r}, {self.scan!r}: {len(self.images)} images)"

    def read_image(self, name: str) -> np.ndarray:
        """RGB uint8 (H, W, 3)."""
        if not self.frames:
            raise BadInputError(self.folder / "jpg_rgb" / name, "scan read metadata-only (frames=False): no frames")
        img = self.images.get(name)
        return read_rgb(img.path if img is not None else self.folder / "jpg_rgb" / name, self.root)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the scan's images, from the first image's JPEG header."""
        if self._image_size is None:
            if not self.images:
                raise BadInputError(self.folder, "scan has no readable images")
            first = next(iter(self.images.values()))
            self._image_size = jpeg_size(first.path, self.root)
        return self._image_size

    def intrinsics(self) -> np.ndarray:
        """3x3 K for the actual image size: cameras.txt (COLMAP) if present, else the authors'
        Kinect calibration at 1920x1080; either is scaled to the image size."""
        w, h = self.image_size
        cam_path = self.folder / "cameras.txt"
        if cam_path.exists() or cam_path.is_symlink():
            (cw, ch), K = _read_colmap_camera(cam_path, self.root)
        else:
            (cw, ch), K = KINECT_SIZE, KINECT_K.copy()
        # COLMAP's rescaling convention: focal lengths and principal point scale together.
        S = np.diag([w / cw, h / ch, 1.0])
        return S @ K

    def boxes_of(self, instance: str, max_difficulty: int = 5) -> list[tuple[AVDImage, AVDBox]]:
        """Every (image, box) of an instance with difficulty <= max_difficulty, by image name."""
        if instance not in self.instance_ids:
            raise KeyError(f"instance {instance!r} is not in {self.root / 'instance_id_map.txt'}")
        iid = self.instance_ids[instance]
        return [(img, b) for img in self.images.values() for b in img.boxes
                if b.instance_id == iid and b.difficulty <= max_difficulty]

    def grid_points(self) -> dict[str, int]:
        """{image: grid point id}: images the robot took from one stop, turning on the spot
        (``pipeline.scene.viewpoints``: the move graph's rotate edges, else chained centres)."""
        return scan_grid_points({n: img.moves for n, img in self.images.items()},
                                {n: img.position for n, img in self.images.items()})


def _read_colmap_camera(path: Path, root: Path | None = None) -> tuple[tuple[int, int], np.ndarray]:
    """((width, height), K) from the first camera in a COLMAP cameras.txt."""
    try:
        text = read_checked(path, root, "cameras.txt").decode("utf-8")
    except UnicodeDecodeError as e:
        raise BadInputError(path, f"not a text file ({e})") from None
    note_read(path)
    for line in text.splitlines():
        toks = line.split()
        if not toks or toks[0].startswith("#"):
            continue
        try:
            model, w, h = toks[1], int(toks[2]), int(toks[3])
            p = [float(x) for x in toks[4:]]
        except (IndexError, ValueError):
            raise BadInputError(path, f"malformed camera line {line!r}") from None
        single_focal = model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL",
                                 "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")
        need = 3 if single_focal else 4  # f cx cy ... | fx fy cx cy ... (PINHOLE, OPENCV, ...)
        if len(p) < need or w <= 0 or h <= 0:
            raise BadInputError(path, f"malformed camera line {line!r}")
        fx, fy, cx, cy = (p[0], p[0], p[1], p[2]) if single_focal else p[:4]
        if fx <= 0 or fy <= 0:
            raise BadInputError(path, f"non-positive focal length in {line!r}")
        return (w, h), np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    raise BadInputError(path, "no camera line found")
