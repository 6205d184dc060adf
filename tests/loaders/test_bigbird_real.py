"""The 6 real BigBIRD frames (../shared/realdata/bigbird_frames) through the reader's mask -> box
path, checked against an independent decode (PIL's PBM reader, scipy's opening and labelling)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.loaders.realdata import need

FRAMES = {"honey_bunches": ("NP1_123", "NP2_342"), "mahatma_rice": ("NP1_228", "NP5_348"),
          "nature_valley": ("NP1_234", "NP2_123")}


def independent_box(path, k: int) -> tuple[int, int, int, int]:
    """Object box from PIL's decode (black = object) with scipy: k x k opening, largest
    8-connected component, exclusive ends."""
    import scipy.ndimage as ndi
    from PIL import Image

    obj = ~np.array(Image.open(path).convert("1"), dtype=bool)
    lab, n = ndi.label(ndi.binary_opening(obj, structure=np.ones((k, k), bool)), structure=np.ones((3, 3), int))
    assert n >= 1, f"{path}: nothing left after the opening"
    big = 1 + int(np.argmax(np.bincount(lab.ravel())[1:]))
    ys, xs = ndi.find_objects((lab == big).astype(np.int32))[0]
    return xs.start, ys.start, xs.stop, ys.stop


@pytest.mark.parametrize("obj,view", [(o, v) for o, vs in FRAMES.items() for v in vs])
def test_real_mask_gives_the_independent_box(obj, view):
    from loaders.bigbird import jpeg_size, mask_box, opening_px, read_rgb
    from loaders.pbm import read_pbm

    root = need("bigbird_frames")
    mask_path, jpg = root / obj / f"{view}.pbm", root / obj / f"{view}.jpg"
    mask = read_pbm(mask_path, root)
    assert mask.shape == (1024, 1280) and jpeg_size(jpg, root) == (1280, 1024)
    assert read_rgb(jpg, root).shape == (1024, 1280, 3)
    assert 0.005 < mask.mean() < 0.5, "black = object: the object is a small part of the frame"
    box = mask_box(mask, where=mask_path)
    assert box == independent_box(mask_path, opening_px(mask.shape))
    x0, y0, x1, y1 = box
    # the box holds the object: nearly every object pixel of the raw mask lies inside it
    assert mask[y0:y1, x0:x1].sum() >= 0.99 * mask.sum()
