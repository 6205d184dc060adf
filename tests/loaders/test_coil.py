"""COIL-100 reader: generated fixtures (a disc on black, bad files of each kind) and the real
folder (../shared/realdata/coil100)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from loaders.coil import CoilFolder, object_mask, object_name
from loaders.errors import BadInputError, SkipLog
from tests.loaders.realdata import need


def _view(size=128, radius=30, value=180) -> np.ndarray:
    img = np.zeros((size, size, 3), np.uint8)
    cv2.circle(img, (size // 2, size // 2), radius, (value, value // 2, 30), -1)
    img[5, 5] = 255  # one bright backdrop speck: the opening removes it
    return img


def _write(folder, name, img):
    cv2.imwrite(str(folder / name), img)


def test_angles_mask_and_missing_views(tmp_path):
    for a in range(0, 360, 5):
        if a not in (15, 200):
            _write(tmp_path, f"obj7__{a}.png", _view())
    coil = CoilFolder(tmp_path)
    assert coil.objects == [7]
    assert [v.angle for v in coil.views(7)][:4] == [0, 5, 10, 20]
    assert coil.missing(7) == [15, 200]
    rgb, mask = coil.read(coil.view(7, 0))
    assert rgb.shape == (128, 128, 3)
    assert not mask[5, 5]  # speck opened away
    ys, xs = np.nonzero(mask)
    assert abs(xs.min() - 34) <= 1 and abs(xs.max() - 94) <= 1 and abs(ys.min() - 34) <= 1
    assert object_name(7) == "coil_obj007"


def test_bad_files_follow_the_skip_policy(tmp_path):
    _write(tmp_path, "obj3__0.png", _view())
    _write(tmp_path, "obj3__5.png", _view(size=32, radius=8))      # wrong size
    _write(tmp_path, "obj3__10.png", np.zeros((128, 128, 3), np.uint8))  # empty mask
    (tmp_path / "obj3__15.png").write_bytes(b"not a png")
    _write(tmp_path, "obj3__7.png", _view())                        # angle off the 5-degree ring
    with pytest.raises(BadInputError, match="obj3__7.png"):
        CoilFolder(tmp_path)
    log = SkipLog("COIL view")
    coil = CoilFolder(tmp_path, skip=log)
    assert log.count == 1
    views = coil.read_object(3)
    assert sorted(views) == [0]
    assert log.count == 4
    assert any("32x32x3" in r for r in log.reasons) and any("empty object mask" in r for r in log.reasons)
    assert any("not a PNG" in r for r in log.reasons)
    with pytest.raises(BadInputError, match="32x32"):
        coil.read(coil.view(3, 5))


def test_mask_threshold_on_dark_object():
    img = np.zeros((16, 16, 3), np.uint8)
    img[4:12, 4:12] = (41, 10, 10)   # just above the threshold on one channel
    assert object_mask(img)[4:12, 4:12].all()
    img[4:12, 4:12] = (40, 40, 40)
    assert not object_mask(img).any()


def test_real_coil_folder():
    folder = need("coil100")
    log = SkipLog("COIL view")
    coil = CoilFolder(folder, skip=log)
    assert coil.objects == list(range(1, 81))
    n = sum(len(coil.views(k)) for k in coil.objects)
    assert n == 5728
    lacking = [k for k in coil.objects if coil.missing(k)]
    assert lacking == [1, 10, 11, 15, 16, 19, 20, 21, 22, 23, 25, 27, 28, 29, 30, 31, 32]
    assert coil.read_object(1) == {} and log.count == len(coil.views(1))  # object 1 is stored at 32x32
    views = coil.read_object(2)
    assert len(views) == 72 and log.count == len(coil.views(1))
    areas = [m.mean() for _, m in views.values()]
    assert 0.02 < min(areas) and max(areas) < 0.9   # a real object, not the whole frame
