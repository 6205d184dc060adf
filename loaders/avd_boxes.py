"""One AVD bounding box ``[x0, y0, x1, y1, instance_id, difficulty]`` (docs/formats/avd.md §3):
parsed, checked against its image, and repaired where the real files show a repairable habit.

What the real scans in ``../shared/realdata/avd`` hold besides the textbook box (counts over the
15 scans, docs/formats/avd.md §3.1):

- difficulty 0 (281 boxes in 8 scans, mostly every box of one instance in a scan): the level was
  never filled in. AVD's difficulty is a function of the box size alone, and the stated level of
  every one of the other 49,553 real boxes equals that function, so the reader assigns it
  (``BoxNotes.unassigned``) instead of refusing a legitimate box;
- boxes past the image edge (3 boxes, 3-11 px past a 1920x1080 frame, 89-98 % of their area
  inside): clipped to the image (``BoxNotes.clipped``). A box with less than half its area inside
  is refused as a defect ("lies outside");
- zero-area boxes (2, Home_003_1, ``x1 == x0`` and ``y1 == y0``): a real defect, refused
  ("degenerate box"), so counted under the skip policy.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from loaders.errors import BadInputError

# A box clipped at the image edge keeps at least this share of its area inside the image; below
# it the box is more wrong than right and is refused (the real overshoots keep 89-98 %).
MIN_INSIDE_FRACTION = 0.5
UNASSIGNED_DIFFICULTY = 0   # the real files' "no level filled in"


@dataclass(frozen=True)
class AVDBox:
    x0: int
    y0: int
    x1: int
    y1: int
    instance_id: int
    difficulty: int


@dataclass
class BoxNotes:
    """Boxes the reader kept after a repair, per scan (logged once per scan, not skips)."""
    unassigned: int = 0   # difficulty 0 in the file: the size rule's level assigned
    clipped: int = 0      # past the image edge: clipped to it

    def as_dict(self) -> dict:
        return {"difficulty_assigned": self.unassigned, "clipped_to_image": self.clipped}


def difficulty(x0: float, y0: float, x1: float, y1: float) -> int:
    """AVD's size-only difficulty (1 easiest .. 5), with w = x1-x0, h = y1-y0."""
    w, h = x1 - x0, y1 - y0
    big, small = max(w, h), min(w, h)
    for level, (lb, ls) in enumerate(((300, 100), (200, 75), (100, 50), (50, 30)), start=1):
        if big >= lb and small >= ls:
            return level
    return 5


def parse_box(b, name: str, w: int, h: int, ann_path: Path, instance_names, notes: BoxNotes) -> AVDBox:
    """The checked box ``b`` of image ``name`` in a ``w`` x ``h`` image; BadInputError naming
    ``ann_path`` and the image for a box that is a defect."""
    if not isinstance(b, (list, tuple)) or len(b) != 6:
        raise BadInputError(ann_path, f"image {name}: box {b!r} is not [x0, y0, x1, y1, id, difficulty]")
    vals = []
    for v in b:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not float(v).is_integer():
            raise BadInputError(ann_path, f"image {name}: box {b!r} has a non-integer value {v!r}")
        vals.append(int(v))
    x0, y0, x1, y1, iid, diff = vals
    if iid not in instance_names or iid == 0:
        raise BadInputError(ann_path, f"image {name}: box {b!r} has unknown instance id {iid}")
    if x1 <= x0 or y1 <= y0:
        raise BadInputError(ann_path, f"image {name}: degenerate box {b!r} (needs x1 > x0 and y1 > y0)")
    if not (diff == UNASSIGNED_DIFFICULTY or 1 <= diff <= 5):
        raise BadInputError(ann_path, f"image {name}: box {b!r} has difficulty {diff}, expected 1..5 "
                                      "(or 0: not assigned)")
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if (cx0, cy0, cx1, cy1) != (x0, y0, x1, y1):
        inside = max(cx1 - cx0, 0) * max(cy1 - cy0, 0)
        if inside < MIN_INSIDE_FRACTION * (x1 - x0) * (y1 - y0):
            raise BadInputError(ann_path, f"image {name}: box {b!r} lies outside the {w}x{h} image "
                                          f"(less than {MIN_INSIDE_FRACTION:.0%} of it inside)")
        # One past the right/bottom edge is MATLAB's inclusive edge (labels drawn 1-based), not a repair.
        if x0 < 0 or y0 < 0 or x1 > w + 1 or y1 > h + 1:
            notes.clipped += 1
        x0, y0, x1, y1 = cx0, cy0, cx1, cy1
    if diff == UNASSIGNED_DIFFICULTY:
        notes.unassigned += 1
        diff = difficulty(x0, y0, x1, y1)
    return AVDBox(x0, y0, x1, y1, iid, diff)
