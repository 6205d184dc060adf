"""Reader for COIL-100 (Nene, Nayar & Murase 1996): turntable photographs of 100 objects.

A COIL folder holds ``obj<k>__<deg>.png``: object ``k`` (1-100) photographed with the turntable
at ``deg`` degrees (0, 5, ..., 355), 128x128 RGB, the object on a black background, the camera
fixed. The angle comes from the name; nothing else is recorded.

The object mask is read off the background: a pixel is object when its largest channel exceeds
``MASK_THRESHOLD`` (40 of 255: the black turntable ground reads 25-30, its 99th percentile near
40, after the dataset's own compression; the darkest object surfaces sit above it), then a 3x3
opening removes isolated bright specks of the ground, a 5x5 closing bridges dark seams and the
holes the object encloses are filled (a dark label or a shadowed inside is object, not ground).
The frames paste the object by this mask (its cut-out), never as the whole square with its ground.
A view whose mask is empty is a bad file.

Bad files follow ``data.skip_bad_views`` (``loaders.errors``, as for BigBIRD): a name that does
not match the pattern, an unreadable PNG, an image that is not 128x128x3 (object 1 of the copy in
``../shared/realdata`` is stored at 32x32: every view of it is skipped with that reason) or an
empty mask raises ``BadInputError`` or, with a ``SkipLog``, is counted and skipped. Views missing
from the 72-view ring (17 objects of the real data lack 1-4) are counted, not errors.
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

NAME_RE = re.compile(r"^obj([1-9][0-9]*)__(0|[1-9][0-9]*)\.png$")
SIZE = (128, 128)          # (width, height) of every COIL-100 image
STEP_DEG = 5               # turntable step: 72 views per object
MASK_THRESHOLD = 40        # max channel above this = object (black backdrop below)


@dataclass(frozen=True)
class CoilView:
    object_id: int
    angle: int             # turntable angle, degrees
    path: Path


def object_name(k: int) -> str:
    """The class name of COIL object ``k`` in viewfuse's files: ``coil_obj<k:03d>``."""
    return f"coil_obj{int(k):03d}"


def object_mask(rgb: np.ndarray) -> np.ndarray:
    """Bool (H, W) object mask of a black-background view: max channel > 40, a 3x3 opening, a 5x5
    closing, then the enclosed holes filled."""
    raw = (np.asarray(rgb).max(axis=2) > MASK_THRESHOLD).astype(np.uint8)
    m = cv2.morphologyEx(raw, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
    return fill_holes(m.astype(bool))


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every background region that does not reach the image border set to True."""
    h, w = mask.shape
    ground = np.ones((h + 2, w + 2), np.uint8)      # a one-pixel frame of ground around the image
    ground[1:-1, 1:-1] = ~mask
    flood = ground.copy()
    cv2.floodFill(flood, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 2)
    return (flood[1:-1, 1:-1] != 2)


class CoilFolder:
    """The views of one COIL-100 folder, indexed by (object, angle).

    ``views(k)`` lists object k's views (sorted by angle); ``missing(k)`` the ring angles it
    lacks; ``read(view)`` decodes and checks one view -> (RGB uint8, mask). Names that do not
    match the pattern are bad entries (counted in ``skip`` or raised)."""

    def __init__(self, folder: str | Path, skip: SkipLog | None = None):
        self.folder = Path(folder)
        self.skip = skip
        if not self.folder.is_dir():
            raise BadInputError(self.folder, "COIL-100 folder is missing")
        self._views: dict[int, dict[int, CoilView]] = {}
        for p in sorted(self.folder.iterdir()):
            if p.suffix.lower() != ".png":
                continue
            m = NAME_RE.match(p.name)
            if m is None or int(m.group(2)) % STEP_DEG or int(m.group(2)) >= 360:
                self._bad(BadInputError(p, "name does not match obj<k>__<deg>.png with deg in 0, 5, ..., 355"))
                continue
            k, a = int(m.group(1)), int(m.group(2))
            self._views.setdefault(k, {})[a] = CoilView(k, a, p)

    def _bad(self, err: BadInputError) -> None:
        if self.skip is None:
            raise err
        self.skip.skip(err)

    @property
    def objects(self) -> list[int]:
        return sorted(self._views)

    def views(self, k: int) -> list[CoilView]:
        if k not in self._views:
            raise BadInputError(self.folder / f"obj{k}__0.png", f"COIL object {k} has no view in the folder")
        return [self._views[k][a] for a in sorted(self._views[k])]

    def view(self, k: int, angle: int) -> CoilView | None:
        return self._views.get(k, {}).get(int(angle))

    def missing(self, k: int) -> list[int]:
        have = self._views.get(k, {})
        return [a for a in range(0, 360, STEP_DEG) if a not in have]

    def read(self, view: CoilView) -> tuple[np.ndarray, np.ndarray]:
        """(RGB uint8 128x128x3, bool mask); ``BadInputError`` for an unreadable or wrong-size file
        or an empty mask (the caller applies the skip policy)."""
        data = read_checked(view.path, self.folder, "COIL-100 image")
        note_read(view.path)
        bgr = decode_image(data, view.path, cv2.IMREAD_UNCHANGED, expect=("PNG",))
        if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8 or bgr.shape[1::-1] != SIZE:
            raise BadInputError(view.path, f"image is {'x'.join(map(str, bgr.shape))} {bgr.dtype}, "
                                           f"expected {SIZE[0]}x{SIZE[1]}x3 uint8 (COIL-100 size)")
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
        mask = object_mask(rgb)
        if not mask.any():
            raise BadInputError(view.path, f"empty object mask (no pixel brighter than {MASK_THRESHOLD})")
        return rgb, mask

    def read_object(self, k: int, angles=None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """{angle: (RGB, mask)} of object k's readable views (optionally only ``angles``); bad
        views follow the skip policy."""
        out = {}
        for v in self.views(k):
            if angles is not None and v.angle not in angles:
                continue
            try:
                out[v.angle] = self.read(v)
            except BadInputError as err:
                self._bad(err)
        return out
