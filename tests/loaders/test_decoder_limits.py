"""The decoder enforces the image limit: headers the gate and OpenCV read differently
are refused by OpenCV's own size limits (set before cv2 is loaded), a file is stat-ed before it is
read and refused when larger than any image within the limit can need, and a file holding more
bytes than its declared size can need is refused before decoding (which bounds the decompression
work). Every case goes through ``vf.read_image``, what outside dataset sources use."""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

import viewfuse as vf
from loaders.errors import BadInputError
from loaders.files import image_bytes_needed, max_megapixels, read_checked, set_max_megapixels
from loaders.image_gate import decoder_limits_active
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.decoder_limits import cap_megapixels


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _ihdr(w: int, h: int) -> bytes:
    return _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))


def _tiff_width_twice() -> bytes:
    """An uncompressed 8-bit grey TIFF whose directory lists ImageWidth twice (20000, then 10) and
    ImageLength 20000: the gate reads one width, libtiff the other."""
    entries = [(256, 4, 1, 20000), (256, 4, 1, 10), (257, 4, 1, 20000), (258, 3, 1, 8), (259, 3, 1, 1),
               (262, 3, 1, 1), (273, 4, 1, 8 + 2 + 12 * 9 + 4), (278, 4, 1, 20000), (279, 4, 1, 100)]
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", *e) for e in entries) + bytes(4)
    return b"II*\x00" + struct.pack("<I", 8) + ifd + bytes(100)


def _hdr_split_line() -> bytes:
    """A Radiance HDR with one 127-character header line: OpenCV reads header lines into a 128-byte
    buffer, so the line's newline alone ends its header and '-Y 8200 +X 8200' is its size; the
    first blank line, which the gate reads, is followed by '-Y 10 +X 10'."""
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n#" + b"x" * 126 + b"\n-Y 8200 +X 8200\n\n-Y 10 +X 10\n" + bytes(400)


def _png_stored_idat(n: int) -> bytes:
    """A PNG declaring 1 x 1 with an IDAT stream of ``n`` stored (uncompressed) bytes: the byte
    count is what is refused, so the test needs no 30000² stream to compress (the issue's 875 KB
    file inflated to 900 MB and decoded for 10.8 s)."""
    return b"\x89PNG\r\n\x1a\n" + _ihdr(1, 1) + _chunk(b"IDAT", zlib.compress(bytes(n), 0)) + _chunk(b"IEND", b"")


CASES = {
    # the cases
    "TIFF listing ImageWidth twice": ("w.tif", _tiff_width_twice(), r"OpenCV's decoder reads a size above its limit"),
    "HDR with a 127-character header line": ("l.hdr", _hdr_split_line(), r"OpenCV's decoder reads a size above its limit"),
    "PNG 1x1 with an oversized IDAT": ("b.png", _png_stored_idat(400_000), r"holds \d+ bytes, more than the 1x1 pixels"),
    # variants the issue does not name
    "PNG with a second IHDR declaring 20000x20000": (
        "t.png", b"\x89PNG\r\n\x1a\n" + _ihdr(10, 10) + _ihdr(20000, 20000) +
        _chunk(b"IDAT", zlib.compress(bytes(110))) + _chunk(b"IEND", b""), r"corrupt PNG"),
    "PGM declaring 10x10 followed by 1 MB": ("p.pgm", b"P5\n10 10\n255\n" + bytes(1 << 20),
                                             r"PGM file holds \d+ bytes, more than the 10x10 pixels"),
    "BMP declaring 10x10 followed by 1 MB": (
        "m.bmp", b"BM" + struct.pack("<IHHI", 54 + (1 << 20), 0, 0, 54) +
        struct.pack("<IiiHHIIiiII", 40, 10, 10, 1, 24, 0, 0, 0, 0, 0, 0) + bytes(1 << 20),
        r"BMP file holds \d+ bytes, more than the 10x10 pixels"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_header_lie_is_refused_naming_the_file_and_cause(tmp_path, name):
    fname, data, cause = CASES[name]
    p = tmp_path / fname
    p.write_bytes(data)
    with pytest.raises(BadInputError, match=cause) as e:
        vf.read_image(p)
    assert str(p) in str(e.value)


def test_opencv_limits_are_in_force_and_the_split_header_is_theirs_to_refuse(tmp_path):
    # the gate alone reads these headers as small: only the decoder's own limit refuses them
    from loaders.image_format import declared_size
    assert declared_size(_hdr_split_line(), "HDR") == (10, 10)
    assert decoder_limits_active()
    assert cap_megapixels() >= max_megapixels()


def test_a_sparse_8_gb_file_named_like_a_view_is_refused_unread(tmp_path):
    p = tmp_path / "obj5__15.png"
    with open(p, "wb") as f:
        f.truncate(8 << 30)             # sparse: no disk used, st_size 8 GB
    for read in (lambda: read_checked(p, tmp_path, "COIL-100 image"), lambda: vf.read_image(p)):
        with pytest.raises(BadInputError, match=r"is 8589934592 bytes, more than any dataset file .* not read") as e:
            read()
        assert str(p) in str(e.value)


def test_a_file_just_under_its_declared_need_still_decodes(tmp_path):
    """The byte bound is what the declared size can need, not a guess: a stored (uncompressed)
    PGM of exactly its pixels plus header decodes."""
    p = tmp_path / "ok.pgm"
    p.write_bytes(b"P5\n40 30\n255\n" + np.arange(1200, dtype=np.uint8).tobytes())
    assert vf.read_image(p).shape == (30, 40, 3)
    assert len(p.read_bytes()) <= image_bytes_needed(40 * 30)


def test_a_limit_above_the_decoders_is_a_config_error_naming_the_key_and_the_remedy():
    old = max_megapixels()
    with pytest.raises(ConfigError, match=r"data.max_image_megapixels = 1e\+06 is above OpenCV's decoder limit"
                                          r".*VIEWFUSE_MAX_IMAGE_MEGAPIXELS"):
        set_max_megapixels(1e6)
    assert max_megapixels() == old


@pytest.mark.parametrize("first,active", [("import viewfuse", True), ("import cv2; import viewfuse", False)])
def test_the_limits_hold_when_the_project_is_loaded_first_and_a_late_load_is_warned(first, active):
    code = (f"{first}\nimport warnings\nfrom loaders.image_gate import decoder_limits_active, decode_image\n"
            "print(decoder_limits_active())\nimport cv2, numpy as np\n"
            "with warnings.catch_warnings(record=True) as w:\n    warnings.simplefilter('always')\n"
            "    decode_image(cv2.imencode('.png', np.zeros((4, 4, 3), np.uint8))[1].tobytes(), 'x.png')\n"
            "print(any('loaded before' in str(x.message) for x in w))\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENCV_IO_")}   # this process set them
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout.split()
    assert out == [str(active), str(not active)]
