"""Every image decoder (COIL PNG, JPEG, PBM) reads the header and checks the declared size against
``data.max_image_megapixels`` before decoding, and every decoder failure (OpenCV's assertions
included) is a named BadInputError that the skip policy counts."""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from loaders.errors import BadInputError, SkipLog


def _png_header(w: int, h: int, depth: int = 16, colour: int = 2, body: bytes = b"") -> bytes:
    """A small PNG that declares w x h (16-bit RGB by default); its data is a few compressed zeros."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(body or bytes(4096))) + \
        chunk(b"IEND", b"")


def _view() -> bytes:
    img = np.zeros((128, 128, 3), np.uint8)
    cv2.circle(img, (64, 64), 30, (200, 150, 100), -1)
    return cv2.imencode(".png", img)[1].tobytes()


CASES = {
    "declares 30000x30000 16-bit RGB": (_png_header(30000, 30000), "declares 30000x30000 pixels"),
    "declares 9000x9000 8-bit grey": (_png_header(9000, 9000, depth=8, colour=0), "declares 9000x9000 pixels"),
    "declares 0x128": (_png_header(0, 128), "declares 0x128 pixels"),
    "0 bytes": (b"", "empty file"),
    "truncated": (_view()[:60], "cannot decode|corrupt PNG"),
    "garbage": (bytes(range(256)) * 4, "not a PNG"),
    "JPEG bytes under a .png name": (cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes(), "not a PNG"),
    "PNG signature only": (b"\x89PNG\r\n\x1a\n", "no header declaring the image size"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_coil_png_cases_are_named_and_skipped(tmp_path, case):
    from loaders.coil import CoilFolder

    data, msg = CASES[case]
    (tmp_path / "obj4__0.png").write_bytes(_view())
    (tmp_path / "obj4__5.png").write_bytes(data)
    coil = CoilFolder(tmp_path)
    with pytest.raises(BadInputError, match=msg) as e:
        coil.read(coil.view(4, 5))
    assert "obj4__5.png" in str(e.value)
    log = SkipLog("COIL view")
    views = CoilFolder(tmp_path, skip=log).read_object(4)
    assert sorted(views) == [0] and log.count == 1


def test_the_png_size_check_follows_the_configured_limit(tmp_path, monkeypatch):
    from loaders import files
    from loaders.coil import CoilFolder

    (tmp_path / "obj4__0.png").write_bytes(_view())
    coil = CoilFolder(tmp_path)
    monkeypatch.setitem(files._limit, "megapixels", 0.01)  # 128 x 128 = 0.016 MP
    with pytest.raises(BadInputError, match=r"declares 128x128 pixels .* data.max_image_megapixels = 0.01"):
        coil.read(coil.view(4, 0))


def test_an_opencv_assertion_becomes_a_named_error(tmp_path, monkeypatch):
    """Whatever OpenCV raises (its own cv2.error) is a bad input naming the file, not a crash."""
    from loaders import coil as coil_mod
    from loaders import jpeg

    def boom(*a, **k):
        raise cv2.error("OpenCV(4.x) error: (-215:Assertion failed) !buf.empty() in function 'imdecode_'")

    (tmp_path / "obj4__0.png").write_bytes(_view())
    c = coil_mod.CoilFolder(tmp_path)
    monkeypatch.setattr(coil_mod.cv2, "imdecode", boom)
    with pytest.raises(BadInputError, match=r"obj4__0.png: corrupt PNG: OpenCV failed"):
        c.read(c.view(4, 0))
    ok = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))  # monkeypatched imdecode only
    with pytest.raises(BadInputError, match=r"x.jpg: corrupt JPEG: OpenCV failed"):
        jpeg.decode_jpeg(ok[1].tobytes(), tmp_path / "x.jpg")


@pytest.mark.parametrize("data,msg", [
    (b"", "empty file"),
    (b"\xff\xd8\xff\xd9", "no header declaring the image size"),
    (_png_header(30000, 30000), "declares 30000x30000"),  # a PNG under a .jpg name
    (b"\xff\xd8\xff\xc0\x00\x11\x08\x75\x30\x75\x30\x03" + bytes(12) + b"\xff\xda" + bytes(8) + b"\xff\xd9",
     "declares 30000x30000"),
])
def test_jpeg_reader_checks_the_header_first(tmp_path, data, msg):
    from loaders.jpeg import read_rgb

    p = tmp_path / "x.jpg"
    p.write_bytes(data)
    with pytest.raises(BadInputError, match=msg):
        read_rgb(p)


@pytest.mark.parametrize("w,h", [(30000, 30000), (100000, 1000)])
def test_pbm_checks_the_declared_size_before_unpacking(tmp_path, w, h):
    from loaders.pbm import read_pbm

    p = tmp_path / "m.pbm"
    p.write_bytes(f"P4\n{w} {h}\n".encode() + bytes(((w + 7) // 8) * 4))
    with pytest.raises(BadInputError, match=f"declares {w}x{h} pixels"):
        read_pbm(p)
