"""Dataset files are read as regular files inside their root: symlinks leaving the root or to
special files, FIFOs, HDF5 external and soft links are refused with the file (and key) named, as
skips where the skip policy allows; an image header declaring too many pixels is refused before
decoding."""
from __future__ import annotations

import os
import threading
import time

import h5py
import numpy as np
import pytest

import loaders.files as files
from loaders.bigbird import BigBirdObject
from loaders.image_format import declared_size
from loaders.jpeg import read_rgb
from loaders.errors import BadInputError, SkipLog
from tests.support import stage_fakes
from tests.support.readers_fixtures import make_avd_scan, make_bigbird_object, write_jpeg

KEY = "H_NP1_from_NP5"


@pytest.fixture
def bb(tmp_path):
    make_bigbird_object(tmp_path / "bb", angles=(0, 3, 6), cameras=(1,))
    return tmp_path / "bb" / "aunt_jemima_original_syrup"


def _relink(cal, make_link):
    with h5py.File(cal, "a") as f:
        del f[KEY]
        make_link(f)


@pytest.mark.parametrize("kind", ["external", "dangling external", "soft loop"])
def test_hdf5_links_are_refused_naming_file_and_key(bb, tmp_path, kind):
    cal = bb / "calibration.h5"
    outside = tmp_path / "outside.h5"
    with h5py.File(outside, "w") as f:
        f["M"] = np.eye(4)
    if kind == "external":
        _relink(cal, lambda f: f.__setitem__(KEY, h5py.ExternalLink(str(outside), "/M")))
    elif kind == "dangling external":
        _relink(cal, lambda f: f.__setitem__(KEY, h5py.ExternalLink(str(tmp_path / "gone.h5"), "/M")))
    else:
        def loop(f):
            f[KEY] = h5py.SoftLink("/loop")
            f["loop"] = h5py.SoftLink("/" + KEY)
        _relink(cal, loop)
    with pytest.raises(BadInputError) as e:
        BigBirdObject(bb).check_calibration((1,))
    assert e.value.path == str(cal) and f"'{KEY}'" in e.value.problem
    assert ("external link" if "external" in kind else "soft link") in e.value.problem


def _views_skipped(folder) -> SkipLog:
    log = SkipLog("view")
    list(BigBirdObject(folder).iter_views((1,), skip=log))
    return log


def test_a_jpeg_symlinked_to_a_device_is_a_named_skip(bb):
    img = bb / "NP1_3.jpg"
    img.unlink()
    os.symlink("/dev/zero", img)
    t0 = time.perf_counter()
    log = _views_skipped(bb)
    assert time.perf_counter() - t0 < 10
    assert log.count == 1 and str(img) in log.examples[0] and "character device" in log.examples[0]


def test_a_jpeg_symlinked_outside_the_root_is_a_named_skip(bb, tmp_path):
    img = bb / "NP1_6.jpg"
    outside = tmp_path / "elsewhere" / "other.jpg"
    outside.parent.mkdir()
    os.replace(img, outside)                     # a valid JPEG, but outside the dataset root
    os.symlink(outside, img)
    log = _views_skipped(bb)
    assert log.count == 1 and "outside the dataset root" in log.examples[0] and str(img) in log.examples[0]
    # a symlink that stays inside the root is fine
    inside = bb.parent / "shared.jpg"
    os.replace(outside, inside)
    img.unlink()
    os.symlink(inside, img)
    assert _views_skipped(bb).count == 0


def test_a_fifo_annotations_file_is_refused_without_blocking(tmp_path):
    from loaders.avd import AVDScan

    scan = make_avd_scan(tmp_path / "avd")
    ann = scan["folder"] / "annotations.json"
    ann.unlink()
    os.mkfifo(ann)
    errors: list[BaseException] = []

    def read():
        try:
            AVDScan(tmp_path / "avd", scan["scan"])
        except BaseException as e:  # noqa: BLE001 - inspected below
            errors.append(e)
    t = threading.Thread(target=read, daemon=True)
    t.start()
    t.join(20)
    assert not t.is_alive(), "the reader blocked on the FIFO"
    assert isinstance(errors[0], BadInputError) and errors[0].path == str(ann)
    assert "FIFO" in errors[0].problem


def _declare_size(data: bytes, w: int, h: int) -> bytes:
    """The same JPEG with its frame header (SOF0) declaring w x h pixels."""
    i = data.index(b"\xff\xc0")
    return data[:i + 5] + h.to_bytes(2, "big") + w.to_bytes(2, "big") + data[i + 9:]


def test_a_huge_declared_jpeg_is_refused_before_decoding(tmp_path, monkeypatch):
    p = tmp_path / "small.jpg"
    write_jpeg(p, np.full((48, 64, 3), 120, np.uint8))
    assert read_rgb(p).shape == (48, 64, 3)
    assert declared_size(p.read_bytes(), "JPEG") == (64, 48)
    huge = tmp_path / "huge.jpg"
    huge.write_bytes(_declare_size(p.read_bytes(), 30000, 30000))
    t0 = time.perf_counter()
    with pytest.raises(BadInputError, match=r"declares 30000x30000 pixels \(900 MP\).*max_image_megapixels"):
        read_rgb(huge)
    assert time.perf_counter() - t0 < 1.0
    monkeypatch.setitem(files._limit, "megapixels", 0.001)   # the limit is configurable
    with pytest.raises(BadInputError, match="declares 64x48"):
        read_rgb(p)


def test_png_headers_are_read_too():
    png = b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\x0dIHDR" + (40000).to_bytes(4, "big") + (50).to_bytes(4, "big")
    assert declared_size(png, "PNG") == (40000, 50)


def test_the_runner_applies_the_configured_limit(tmp_config, monkeypatch):
    seen = []
    stage_fakes.install(monkeypatch, {"a": ()}, {"a": lambda ctx: seen.append(files.max_megapixels())})
    monkeypatch.setitem(files._limit, "megapixels", files.DEFAULT_MAX_MEGAPIXELS)
    import stages.framework.runner as runner
    runner.ensure(tmp_config({"data": {"max_image_megapixels": 5.0}}), "a")
    assert seen == [5.0]
