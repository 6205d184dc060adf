"""ETH-80 reader: generated fixtures (a disc on blue with its map, bad files of each kind, both
folder layouts) and the real folder (../shared/realdata/eth80)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from loaders.errors import BadInputError, SkipLog
from loaders.eth80 import MASK_THRESHOLD, Eth80Folder, snap_azimuth
from loaders.files import max_megapixels, set_max_megapixels
from tests.loaders.realdata import need

NAMES = ["000", "022", "045", "068", "090", "112", "135", "158", "180", "202", "225", "248", "270", "292", "315", "338"]


def _write(folder, prefix, az, size=64, radius=12, maps="beside"):
    folder.mkdir(parents=True, exist_ok=True)
    img = np.zeros((size, size, 3), np.uint8)
    img[:] = (160, 60, 40)  # blue cloth (BGR)
    cv2.circle(img, (size // 2, size // 2), radius, (30, 200, 230), -1)
    m = np.zeros((size, size), np.uint8)
    cv2.circle(m, (size // 2, size // 2), radius, 255, -1)
    m = cv2.GaussianBlur(m, (5, 5), 1.0)   # soft edges, as the dataset's maps
    cv2.imwrite(str(folder / f"{prefix}-090-{az}.png"), img)
    mdir = folder / "maps" if maps == "maps" else folder
    mdir.mkdir(exist_ok=True)
    cv2.imwrite(str(mdir / f"{prefix}-090-{az}-map.png"), m)
    return m


def test_names_azimuths_and_mask(tmp_path):
    for az in NAMES:
        m = _write(tmp_path / "cup3", "cup3", az)
    _write(tmp_path / "car4", "car12", "022")   # the folder names the instance, not the prefix
    eth = Eth80Folder(tmp_path)
    assert eth.objects == [("car", 4), ("cup", 3)]
    vs = eth.views("cup", 3)
    assert [v.azimuth for v in vs] == [k * 22.5 for k in range(16)]
    assert eth.views("car", 4)[0].azimuth == 22.5 and eth.views("car", 4)[0].instance == 4
    rgb, mask, alpha = eth.read(vs[0])
    assert rgb.shape == (64, 64, 3) and rgb[0, 0].tolist() == [40, 60, 160]   # RGB order
    np.testing.assert_array_equal(mask, m >= MASK_THRESHOLD)
    assert 0 < mask.sum() < 64 * 64 and alpha.max() == 1.0 and alpha.min() == 0.0


def test_snap_azimuth_reads_half_to_even_names():
    for k in range(16):
        name = int(round(k * 22.5))   # Python rounds half to even, as the names do
        assert snap_azimuth(name) == k * 22.5
    assert snap_azimuth(23) == 22.5 and snap_azimuth(30) == 30.0   # another ring keeps its integer


def test_category_layout_and_maps_folder(tmp_path):
    _write(tmp_path / "horse" / "horse10", "horse10", "000", maps="maps")
    eth = Eth80Folder(tmp_path)
    assert eth.objects == [("horse", 10)]
    assert eth.views("horse", 10)[0].map_path.parent.name == "maps"
    assert eth.read_instance("horse", 10)[0.0][1].any()


def test_bad_files_are_errors_or_counted_skips(tmp_path):
    for az in ("000", "022", "045", "068", "090"):
        _write(tmp_path / "dog2", "dog2", az)
    d = tmp_path / "dog2"
    (d / "dog2-090-xyz.png").write_bytes(b"x")                      # bad name
    (d / "dog2-090-045-map.png").unlink()                            # view without its map
    (d / "dog2-090-068.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")   # undecodable
    cv2.imwrite(str(d / "dog2-090-090-map.png"), np.zeros((64, 64), np.uint8))   # empty mask
    cv2.imwrite(str(d / "dog2-090-022-map.png"), np.zeros((32, 32), np.uint8))   # map of another size
    with pytest.raises(BadInputError, match="map <name>-map.png is missing"):   # the first bad file, in name order
        Eth80Folder(tmp_path)
    log = SkipLog("ETH-80 view")
    eth = Eth80Folder(tmp_path, skip=log)
    got = eth.read_instance("dog", 2)
    assert sorted(got) == [0.0]
    assert log.count == 5, log.examples
    assert any("does not match" in e for e in log.examples) and any("decode" in e for e in log.examples)
    assert any("map is 32x32" in e for e in log.examples)
    with pytest.raises(BadInputError, match="empty object mask"):
        Eth80Folder(tmp_path, skip=SkipLog("x")).read(eth.views("dog", 2)[-1])


def test_header_size_checked_before_decoding(tmp_path):
    _write(tmp_path / "pear1", "pear1", "000")
    eth = Eth80Folder(tmp_path)
    old = max_megapixels()
    set_max_megapixels(0.001)   # 64 x 64 = 0.004 MP: refused from the header
    try:
        with pytest.raises(BadInputError, match="max_image_megapixels"):
            eth.read(eth.views("pear", 1)[0])
    finally:
        set_max_megapixels(old)


def test_real_folder_counts():
    root = need("eth80")
    log = SkipLog("ETH-80 view")
    eth = Eth80Folder(root, skip=log)
    assert log.count == 0
    assert eth.categories() == ["apple", "car", "cow", "cup", "dog", "horse", "pear", "tomato"]
    assert all(eth.instances(c) == list(range(1, 10)) for c in eth.categories())
    assert sum(len(eth.views(c, i)) for c, i in eth.objects) == 1152
    for c, i in eth.objects:
        vs = eth.views(c, i)
        assert [v.azimuth for v in vs] == [k * 22.5 for k in range(16)] and {v.elevation for v in vs} == {90}
    assert eth.views("car", 4)[0].path.name.startswith("car12-") and eth.views("car", 8)[0].path.name.startswith("car14-")
    for c, i in ((car, n) for car in ("car", "cup") for n in (1, 9)):
        rgb, mask, alpha = eth.read(eth.views(c, i)[3])
        assert rgb.shape == (128, 128, 3) and 0.05 < mask.mean() < 0.9
