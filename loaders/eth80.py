"""Reader for ETH-80 (Leibe & Schiele 2003): photographs of 8 object categories x 10 instances.

An ETH-80 root holds one folder per instance, ``<category><n>/`` (``apple1/``, ..., ``tomato10/``),
either directly or under a category folder (``apple/apple1/``, the layout of some downloads). A
view is ``<prefix>-<elevation>-<azimuth>.png`` (RGB, square: 128 px in ``../shared/realdata``, 256
in the cropped download) and its segmentation map ``<prefix>-<elevation>-<azimuth>-map.png``
beside it or in ``maps/``. The FOLDER names the instance: two folders of the copy used here hold
files under another instance's prefix (``car4/`` holds ``car12-*``), as in its source.

Azimuth: the names write k x 22.5 degrees rounded half-to-even (``022``, ``068``, ...), so a name
within 0.5 degree of a multiple of 22.5 is read as that multiple (``azimuth``, float degrees); any
other integer is kept as written (the other rings of the full dataset). ``elevation`` is the
name's integer (90 = the equatorial ring in the dataset's own numbering).

Mask: the map is 8-bit grey, object ~255 with soft edges; a pixel is object when its map value is
at least ``MASK_THRESHOLD`` = 128 (half way: the soft rim, about 3 % of the pixels, splits evenly).

Bad files follow ``data.skip_bad_views`` as for COIL-100 (``loaders.coil``): a name that does not
match, a view without its map, a header declaring more than ``data.max_image_megapixels`` (checked
before decoding, ``loaders.image_gate``), a file that is not a decodable PNG, an image that is not
square (decoded as 8-bit colour), a map of another size or an empty mask raise ``BadInputError`` or, with a
``SkipLog``, are counted and skipped.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from loaders.errors import BadInputError, SkipLog
from loaders.files import read_checked
from loaders.image_gate import decode_image
from pipeline.infra.cache import note_read

CATEGORIES = ("apple", "car", "cow", "cup", "dog", "horse", "pear", "tomato")
FOLDER_RE = re.compile(r"^([a-z]+)([1-9][0-9]*)$")
VIEW_RE = re.compile(r"^([a-z]+[0-9]+)-([0-9]{3})-([0-9]{3})\.png$")
STEP_DEG = 22.5            # azimuth step of the equatorial ring
MASK_THRESHOLD = 128       # map value >= this = object
MIN_SIDE = 16


@dataclass(frozen=True)
class Eth80View:
    category: str
    instance: int          # from the folder name
    elevation: int
    azimuth: float         # degrees: the nearest multiple of 22.5 when the name is within 0.5 of one
    path: Path
    map_path: Path


def snap_azimuth(name_deg: int) -> float:
    """The azimuth a name means: the multiple of 22.5 within 0.5 degree of it, else the name."""
    k = round(name_deg / STEP_DEG)
    return (k * STEP_DEG) % 360.0 if abs(k * STEP_DEG - name_deg) <= 0.5 else float(name_deg)


def class_object(category: str, instance: int) -> str:
    """The scene object name of one ETH-80 instance: ``eth80_<category><n>``."""
    return f"eth80_{category}{int(instance)}"


class Eth80Folder:
    """The views of an ETH-80 root, indexed by (category, instance). ``read(view)`` decodes and
    checks one view -> (RGB uint8, bool mask, float map in [0, 1])."""

    def __init__(self, root: str | Path, skip: SkipLog | None = None):
        self.root = Path(root)
        self.skip = skip
        if not self.root.is_dir():
            raise BadInputError(self.root, "ETH-80 folder is missing")
        self._views: dict[tuple[str, int], list[Eth80View]] = {}
        for folder in self._instance_folders():
            m = FOLDER_RE.match(folder.name)
            cat, inst = m.group(1), int(m.group(2))
            for p in sorted(folder.iterdir()):
                if p.suffix.lower() != ".png" or p.name.endswith("-map.png"):
                    continue
                v = VIEW_RE.match(p.name)
                if v is None:
                    self._bad(BadInputError(p, "name does not match <object>-<elevation>-<azimuth>.png"))
                    continue
                if int(v.group(3)) >= 360:
                    self._bad(BadInputError(p, f"azimuth {v.group(3)} is not below 360"))
                    continue
                mp = next((q for q in (folder / f"{p.stem}-map.png", folder / "maps" / f"{p.stem}-map.png")
                           if q.exists()), None)
                if mp is None:
                    self._bad(BadInputError(p, "segmentation map <name>-map.png is missing (beside it or in maps/)"))
                    continue
                self._views.setdefault((cat, inst), []).append(
                    Eth80View(cat, inst, int(v.group(2)), snap_azimuth(int(v.group(3))), p, mp))
        for vs in self._views.values():
            vs.sort(key=lambda v: (v.elevation, v.azimuth))

    def _instance_folders(self) -> list[Path]:
        out = []
        for d in sorted(p for p in self.root.iterdir() if p.is_dir()):
            if FOLDER_RE.match(d.name):
                out.append(d)
            elif d.name in CATEGORIES:   # <category>/<category><n>/ layout
                out.extend(sorted(q for q in d.iterdir() if q.is_dir() and FOLDER_RE.match(q.name)))
        return out

    def _bad(self, err: BadInputError) -> None:
        if self.skip is None:
            raise err
        self.skip.skip(err)

    @property
    def objects(self) -> list[tuple[str, int]]:
        return sorted(self._views)

    def categories(self) -> list[str]:
        return sorted({c for c, _ in self._views})

    def instances(self, category: str) -> list[int]:
        return sorted(i for c, i in self._views if c == category)

    def views(self, category: str, instance: int, elevations=None) -> list[Eth80View]:
        if (category, int(instance)) not in self._views:
            raise BadInputError(self.root / f"{category}{instance}", f"ETH-80 {category}{instance} has no view")
        return [v for v in self._views[(category, int(instance))] if elevations is None or v.elevation in elevations]

    def read(self, view: Eth80View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(RGB uint8 HxWx3, bool mask, map as float32 in [0, 1]); ``BadInputError`` for a bad
        file (the caller applies the skip policy)."""
        rgb = _decode(view.path, self.root, cv2.IMREAD_COLOR, "ETH-80 image")
        grey = _decode(view.map_path, self.root, cv2.IMREAD_GRAYSCALE, "ETH-80 segmentation map")
        h, w = rgb.shape[:2]
        if h != w or h < MIN_SIDE:
            raise BadInputError(view.path, f"image is {w}x{h}, expected a square of at least {MIN_SIDE} px (ETH-80)")
        if grey.shape != (h, w):
            raise BadInputError(view.map_path, f"map is {grey.shape[1]}x{grey.shape[0]}, its image {w}x{h}")
        mask = grey >= MASK_THRESHOLD
        if not mask.any():
            raise BadInputError(view.map_path, f"empty object mask (no map value >= {MASK_THRESHOLD})")
        return np.ascontiguousarray(rgb[:, :, ::-1]), mask, grey.astype(np.float32) / 255.0

    def read_instance(self, category: str, instance: int, elevations=None) -> dict[float, tuple]:
        """{azimuth: (RGB, mask, map)} of one instance's readable views on ``elevations``; bad views
        follow the skip policy. Two views of one azimuth (several rings) keep the first ring's."""
        out = {}
        for v in self.views(category, instance, elevations):
            try:
                out.setdefault(v.azimuth, self.read(v))
            except BadInputError as err:
                self._bad(err)
        return out


def _decode(path: Path, root: Path, flag: int, what: str) -> np.ndarray:
    data = read_checked(path, root, what)
    note_read(path)
    img = decode_image(data, path, flag, expect=("PNG",))
    if img.dtype != np.uint8:
        raise BadInputError(path, "cannot decode the PNG as 8-bit")
    return img
