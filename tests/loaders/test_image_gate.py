"""The one image gate (``loaders.image_gate``): for every format this OpenCV decodes by content,
the size its header declares is read and checked before decoding; a bomb, a truncated file, a
garbage or empty file of any format ends in a BadInputError naming the file (the decoder is never
called for a refused header), through the gate and through the readers that use it. Every fixture
is written here: small images encoded by OpenCV, then their size fields patched by hand."""
from __future__ import annotations

import ast
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from loaders.errors import BadInputError, SkipPolicy
from loaders.image_format import declared_size, sniff
from loaders.image_gate import checked_image, decode_image

ROOT = Path(__file__).resolve().parents[2]
W, H = 50, 40           # every fixture's true size
BIG = 12000             # 12000 x 12000 = 144 MP, above the 64 MP default limit


def _image() -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[8:32, 10:40] = (200, 120, 40)
    cv2.circle(img, (25, 20), 9, (30, 220, 90), -1)
    return img


def _encode(ext: str, img: np.ndarray, params=()) -> bytes:
    ok, buf = cv2.imencode(ext, img, list(params))
    assert ok, ext
    return buf.tobytes()


def _fixtures() -> dict[str, bytes]:
    """One small image per format; a format this OpenCV build cannot write is left out."""
    img = _image()
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    hdr = img.astype(np.float32) / 255
    bgra = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    bgra[:, :20, 3] = 128   # a real alpha channel: lossy WebP then needs the extended (VP8X) layout
    specs = {
        "PNG": (".png", img, ()), "JPEG": (".jpg", img, ()),
        "WebP lossless (VP8L)": (".webp", img, (cv2.IMWRITE_WEBP_QUALITY, 101)),
        "WebP lossy (VP8)": (".webp", img, (cv2.IMWRITE_WEBP_QUALITY, 80)),
        "WebP extended (VP8X)": (".webp", bgra, (cv2.IMWRITE_WEBP_QUALITY, 80)),
        "TIFF": (".tiff", img, ()), "PBM": (".pbm", grey, ()), "PGM": (".pgm", grey, ()),
        "PPM": (".ppm", img, ()), "PAM": (".pam", img, ()), "PFM": (".pfm", hdr, ()),
        "BMP": (".bmp", img, ()), "GIF": (".gif", img, ()), "JP2": (".jp2", img, ()),
        "HDR": (".hdr", hdr, ()), "Sun raster": (".ras", img, ()), "AVIF": (".avif", img, ()),
    }
    out = {}
    for name, (ext, pixels, params) in specs.items():
        try:
            out[name] = _encode(ext, pixels, params)
        except (cv2.error, AssertionError):
            continue
    if "JP2" in out:
        out["J2K codestream"] = out["JP2"][out["JP2"].index(b"\xff\x4f\xff\x51"):]
    webp = [("WebP lossless (VP8L)", b"VP8L"), ("WebP lossy (VP8)", b"VP8 "), ("WebP extended (VP8X)", b"VP8X")]
    for name, chunk in webp:
        assert out[name][12:16] == chunk, name
    return out


FIXTURES = _fixtures()


def _tiff_patch(data: bytes, w: int, h: int, tiles: tuple[int, int] | None = None) -> bytes:
    """The same TIFF with ImageWidth/ImageLength (or the tile fields) rewritten in place."""
    b = bytearray(data)
    o = "<" if data[:2] == b"II" else ">"
    ifd = struct.unpack_from(o + "I", b, 4)[0]
    for k in range(struct.unpack_from(o + "H", b, ifd)[0]):
        at = ifd + 2 + 12 * k
        tag, typ = struct.unpack_from(o + "HH", b, at)
        new = {256: w, 257: h}.get(tag)
        if new is not None:
            struct.pack_into(o + "HHII", b, at, tag, 4, 1, new)  # as LONG: 33 million rows need it
    if tiles is not None:  # append two entries (322, 323) by rewriting the count: enough for a header reader
        n = struct.unpack_from(o + "H", b, ifd)[0]
        entries = b[ifd + 2:ifd + 2 + 12 * n] + struct.pack(o + "HHII", 322, 4, 1, tiles[0]) + \
            struct.pack(o + "HHII", 323, 4, 1, tiles[1])
        b += struct.pack(o + "H", n + 2) + entries + b"\0\0\0\0"
        struct.pack_into(o + "I", b, 4, len(data))
    return bytes(b)


def declare(name: str, data: bytes, w: int, h: int) -> bytes:
    """``data`` (the fixture ``name``) with its header declaring ``w`` x ``h``: the bytes a bomb
    would hold (the payload stays small)."""
    b = bytearray(data)
    if name == "PNG":
        struct.pack_into(">II", b, 16, w, h)
    elif name == "JPEG":
        struct.pack_into(">HH", b, data.index(b"\xff\xc0") + 5, h, w)
    elif name.startswith("WebP"):
        kind = data[12:16]
        if kind == b"VP8X":
            b[24:27], b[27:30] = (w - 1).to_bytes(3, "little"), (h - 1).to_bytes(3, "little")
        elif kind == b"VP8L":
            bits = struct.unpack_from("<I", b, 21)[0] & ~((1 << 28) - 1)
            struct.pack_into("<I", b, 21, bits | (w - 1) | ((h - 1) << 14))
        else:
            struct.pack_into("<HH", b, 26, w, h)
    elif name == "TIFF":
        return _tiff_patch(data, w, h)
    elif name in ("PBM", "PGM", "PPM", "PFM"):
        return re.sub(rb"^(P.\s+)\d+\s+\d+", rb"\g<1>%d %d" % (w, h), data, count=1)
    elif name == "PAM":
        return re.sub(rb"HEIGHT \d+", b"HEIGHT %d" % h, re.sub(rb"WIDTH \d+", b"WIDTH %d" % w, data, 1), 1)
    elif name == "BMP":
        struct.pack_into("<ii", b, 18, w, h)
    elif name == "GIF":
        struct.pack_into("<HH", b, 6, w, h)
    elif name in ("JP2", "J2K codestream"):
        struct.pack_into(">II", b, data.index(b"\xff\x4f\xff\x51") + 8, w, h)
    elif name == "HDR":
        return re.sub(rb"-Y \d+ \+X \d+", b"-Y %d +X %d" % (h, w), data, count=1)
    elif name == "Sun raster":
        struct.pack_into(">II", b, 4, w, h)
    elif name == "AVIF":
        for m in re.finditer(rb"ispe", data):
            struct.pack_into(">II", b, m.end() + 4, w, h)
    else:
        raise AssertionError(name)
    return bytes(b)


@pytest.fixture
def no_decoder(monkeypatch):
    """cv2.imdecode fails the test if called: a refused header must stop before the decoder."""
    def called(*a, **k):
        raise AssertionError("the decoder was called")
    monkeypatch.setattr(cv2, "imdecode", called)


def test_every_format_recognised_has_a_size_reader():
    from loaders import image_format
    assert {name for name, _ in image_format._SIGNATURES} == set(image_format._READERS)


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_every_format_is_sized_as_the_decoder_sees_it(tmp_path, name):
    data = FIXTURES[name]
    fmt, w, h = checked_image(data, tmp_path / "x.img")
    assert (w, h) == (W, H) and fmt == sniff(data)
    img = decode_image(data, tmp_path / "x.img", cv2.IMREAD_COLOR)
    assert img.shape == (H, W, 3)


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_a_huge_declared_size_is_refused_before_decoding(tmp_path, no_decoder, name):
    bomb = declare(name, FIXTURES[name], BIG, BIG)
    assert len(bomb) < 64 << 10   # a small file
    p = tmp_path / "bomb.png"     # the name says PNG whatever the content: the gate reads the bytes
    with pytest.raises(BadInputError, match=rf"bomb\.png: image declares {BIG}x{BIG} pixels \(144 MP\), "
                                             r"above the limit data.max_image_megapixels = 64; not decoded"):
        decode_image(bomb, p)
    w, h = (16383, 4097) if name in _NARROW_FIELDS else (2, 33_000_000)   # just above 64 MP
    with pytest.raises(BadInputError, match=f"declares {w}x{h} pixels"):
        decode_image(declare(name, FIXTURES[name], w, h), p)
    if name not in _MINUS_ONE:
        with pytest.raises(BadInputError, match=r"declares 0x40 pixels; corrupt header|reference grid 0x40"):
            decode_image(declare(name, FIXTURES[name], 0, H), p)


# size fields of 14 to 24 bits cannot declare 33 million rows; WebP's minus-one fields
# cannot declare 0
_NARROW_FIELDS = {"JPEG", "GIF", "WebP lossy (VP8)", "WebP lossless (VP8L)", "WebP extended (VP8X)"}
_MINUS_ONE = {"WebP lossless (VP8L)", "WebP extended (VP8X)"}


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("keep", [0.6, 0.3, 14])
def test_a_truncated_file_is_a_named_error(tmp_path, name, keep):
    data = FIXTURES[name]
    cut = data[:keep if isinstance(keep, int) else int(len(data) * keep)]
    p = tmp_path / f"cut{Path(name).suffix}.img"
    with pytest.raises(BadInputError) as e:
        decode_image(cut, p)
    assert e.value.path == str(p) and re.search(r"corrupt|truncated|not an image", e.value.problem), e.value.problem


@pytest.mark.parametrize("ext", [".png", ".jpg", ".webp", ".tif", ".pgm", ".bmp", ".gif", ".jp2", ".hdr", ".avif"])
def test_garbage_and_empty_files_never_reach_the_decoder(tmp_path, no_decoder, ext):
    rng = np.random.default_rng(len(ext))
    for data, msg in [(b"", "empty file"), (rng.bytes(2048), "not an image format"),
                      (b"\0" * 64, "not an image format"), (b"<html>not found</html>", "not an image format")]:
        with pytest.raises(BadInputError, match=msg) as e:
            decode_image(data, tmp_path / f"x{ext}")
        assert e.value.path == str(tmp_path / f"x{ext}")


@pytest.mark.parametrize("data,problem", [
    (b"RIFF\0\0\0\0WEBPVP8Q" + bytes(32), "unknown WebP chunk"),
    (b"II*\x00" + struct.pack("<I", 1 << 30), "corrupt TIFF"),             # IFD past the end
    (b"MM\x00*\x00\x00\x00\x08\x00\x01" + struct.pack(">HHII", 259, 3, 1, 1) + bytes(4), "no ImageWidth"),
    (b"GIF89a" + struct.pack("<HHBBB", 50, 40, 0, 0, 0) + b";", "no image descriptor"),
    (b"P6\n50 x\n255\n", "bad size"),
    (b"P7\nWIDTH 50\n", "no ENDHDR"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+Q 40 +X 50\n", "bad resolution line"),
    (b"\x00\x00\x00\x18ftypavif\x00\x00\x00\x00avifmif1", "no image size property"),
    (b"\xff\x4f\xff\x51" + struct.pack(">HH8I", 41, 0, 50, 40, 60, 0, 50, 40, 0, 0), "outside the reference grid"),
    (b"BM\0\0ftypavif" + bytes(32), "signatures of BMP and AVIF; ambiguous"),   # OpenCV's order would decide
])
def test_unreadable_headers_are_named(tmp_path, no_decoder, data, problem):
    with pytest.raises(BadInputError, match=problem) as e:
        decode_image(data, tmp_path / "h.img")
    assert e.value.path == str(tmp_path / "h.img")


def test_variants_with_a_second_size_field(tmp_path, no_decoder):
    """A size field the audit did not name: a GIF frame reaching past a small screen, TIFF tiles
    larger than their image, BigTIFF, a big-endian TIFF, an OS/2 BMP, a top-down BMP."""
    gif = bytearray(FIXTURES["GIF"])
    at = gif.index(b"\x2c", 13)
    while struct.unpack_from("<HHHH", gif, at + 1)[2:] != (W, H):  # the image descriptor, not a palette byte
        at = gif.index(b"\x2c", at + 1)
    struct.pack_into("<HH", gif, at + 5, BIG, BIG)
    bigtiff = b"II+\x00" + struct.pack("<HHQQ", 8, 0, 16, 2) + struct.pack("<HHQQ", 256, 16, 1, BIG) + \
        struct.pack("<HHQQ", 257, 16, 1, BIG)
    mm = b"MM\x00*" + struct.pack(">IH", 8, 2) + struct.pack(">HHIHH", 256, 3, 1, BIG, 0) + \
        struct.pack(">HHII", 257, 4, 1, BIG) + bytes(4)
    os2 = b"BM" + bytes(12) + struct.pack("<IHH", 12, BIG, BIG) + bytes(8)
    topdown = bytearray(FIXTURES["BMP"])
    struct.pack_into("<ii", topdown, 18, BIG, -BIG)
    for data in (bytes(gif), bigtiff, mm, os2, bytes(topdown)):
        with pytest.raises(BadInputError, match=f"declares {BIG}x{BIG} pixels"):
            decode_image(data, tmp_path / "v.img")
    with pytest.raises(BadInputError, match=r"declares 65535x65535 tiles in a 50x40 image"):
        decode_image(_tiff_patch(FIXTURES["TIFF"], W, H, tiles=(65535, 65535)), tmp_path / "t.tif")


def test_the_limit_follows_the_configuration_for_every_format(tmp_path, monkeypatch):
    from loaders import files
    monkeypatch.setitem(files._limit, "megapixels", 0.001)   # 50 x 40 = 0.002 MP
    for name, data in FIXTURES.items():
        with pytest.raises(BadInputError, match="declares 50x40 pixels"):
            checked_image(data, tmp_path / "x.img")


def test_every_decoder_failure_is_named(tmp_path, monkeypatch):
    """None, cv2.error and an image larger than its header are BadInputErrors naming the file."""
    p = tmp_path / "x.webp"
    data = FIXTURES["WebP lossy (VP8)"]
    for result, msg in [(None, "corrupt WebP: OpenCV could not decode it"),
                        (cv2.error("(-215:Assertion failed) in function 'imdecode_'"), "corrupt WebP: OpenCV failed"),
                        (np.zeros((H + 1, W, 3), np.uint8), "decoded 50x41 pixels, more than the 50x40")]:
        def fake(*a, result=result, **k):
            if isinstance(result, Exception):
                raise result
            return result
        monkeypatch.setattr(cv2, "imdecode", fake)
        with pytest.raises(BadInputError, match=msg) as e:
            decode_image(data, p)
        assert e.value.path == str(p)


def test_opencv_s_own_message_is_kept_and_not_printed(tmp_path, capfd):
    cut = FIXTURES["BMP"][:len(FIXTURES["BMP"]) // 2]
    with pytest.raises(BadInputError, match=r"corrupt BMP: OpenCV could not decode it \(.+\)"):
        decode_image(cut, tmp_path / "x.bmp")
    assert "imdecode" not in capfd.readouterr().err


def test_a_reader_expecting_one_format_names_the_other(tmp_path, no_decoder):
    with pytest.raises(BadInputError, match=r"not a PNG: the content is TIFF; refused"):
        checked_image(FIXTURES["TIFF"], tmp_path / "x.png", expect=("PNG",))
    with pytest.raises(BadInputError, match=r"not a PNG or JPEG \(no PNG or JPEG signature\)"):
        checked_image(b"\0" * 32, tmp_path / "x.png", expect=("PNG", "JPEG"))
    assert declared_size(FIXTURES["PPM"], "PPM") == (W, H)


BOMB_NAMES = ["WebP lossless (VP8L)", "WebP lossy (VP8)", "TIFF", "PPM", "BMP", "GIF", "Sun raster", "PNG"]


def _eth80_folder(root: Path, bombs: dict[str, bytes]) -> None:
    good = _encode(".png", np.full((64, 64, 3), 90, np.uint8))
    mask = np.zeros((64, 64), np.uint8)
    cv2.circle(mask, (32, 32), 12, 255, -1)
    folder = root / "cup1"
    folder.mkdir(parents=True)
    (folder / "cup1-090-338.png").write_bytes(good)   # the last view: read after every bomb
    (folder / "cup1-090-338-map.png").write_bytes(_encode(".png", mask))
    for k, data in enumerate(bombs.values()):
        az = f"{int(round((k + 1) * 22.5)):03d}"
        (folder / f"cup1-090-{az}.png").write_bytes(data)
        (folder / f"cup1-090-{az}-map.png").write_bytes(_encode(".png", mask))


def test_readers_skip_bombs_of_every_format_by_name(tmp_path, no_decoder):
    """The ETH-80 and clutter readers (the audit's two) count every bomb as a named skip."""
    from loaders.eth80 import Eth80Folder
    from loaders.real_imagery.clutter import read_backgrounds

    bombs = {n: declare(n, FIXTURES[n], BIG, BIG) for n in BOMB_NAMES}
    _eth80_folder(tmp_path / "eth", bombs)
    policy = SkipPolicy(True)
    eth = Eth80Folder(tmp_path / "eth", skip=policy.log("eth80"))
    with pytest.raises(AssertionError, match="decoder was called"):   # the good view reaches it
        eth.read_instance("cup", 1)
    assert policy.count == len(bombs)
    assert all(f"declares {BIG}x{BIG}" in e for e in policy.summary()["eth80"]["examples"])
    frames = tmp_path / "frames"
    frames.mkdir()
    for k, data in enumerate(bombs.values()):
        (frames / f"f{k}.{'jpg' if k % 2 else 'png'}").write_bytes(data)
    with pytest.raises(BadInputError, match="holds no readable background frame"):
        read_backgrounds(frames, policy)
    assert policy.summary()["avd_frames"]["skipped"] == len(bombs)


_RSS_SCRIPT = r"""
import json, sys
from pathlib import Path
import numpy as np
from loaders.errors import BadInputError
from loaders.files import set_max_megapixels
from loaders.image_gate import decode_image
decode_image(Path(sys.argv[2]).read_bytes(), sys.argv[2])  # a small image: the decoders warmed up
set_max_megapixels(float(sys.argv[1]))
def vm(key):
    return next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith(key + ":"))
# ru_maxrss keeps the forking parent's peak across exec: reset the high-water mark instead
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
before = vm("VmRSS")
refused = 0
for p in sys.argv[3:]:
    try:
        decode_image(Path(p).read_bytes(), p)
    except BadInputError:
        refused += 1
print(json.dumps({"kib": vm("VmHWM") - before, "refused": refused}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc/self/clear_refs")
def test_peak_memory_stays_bounded_with_real_bombs(tmp_path):
    """Real bombs (valid 9 MP WebP and JPEG 2000 files of a few hundred bytes, 27 MB decoded) in a
    fresh process with the real OpenCV: under a 1 MP limit all are refused and the peak resident
    size grows by less than 8 MiB; the same files under a 100 MP limit grow it by more than 20 MiB
    (so the measure can see a decode)."""
    zeros = np.zeros((3000, 3000, 3), np.uint8)
    bombs = []
    for ext, params in [(".webp", (cv2.IMWRITE_WEBP_QUALITY, 101)), (".jp2", ())]:
        bombs.append(tmp_path / f"bomb{ext}")
        bombs[-1].write_bytes(_encode(ext, zeros, params))
        assert bombs[-1].stat().st_size < 4096
    small = tmp_path / "small.png"
    small.write_bytes(FIXTURES["PNG"])
    env = {**os.environ, "PYTHONPATH": str(ROOT), "VIEWFUSE_MAX_IMAGE_MEGAPIXELS": "100"}   # the control's limit

    def peak(limit_mp: float) -> dict:
        out = subprocess.run([sys.executable, "-c", _RSS_SCRIPT, str(limit_mp), str(small), *map(str, bombs)],
                             capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout.strip().splitlines()[-1])
    gated, control = peak(1.0), peak(100.0)
    assert gated["refused"] == len(bombs) and gated["kib"] < 8 * 1024, gated
    assert control["refused"] == 0 and control["kib"] > 20 * 1024, control


# Decoding calls allowed outside the gate: a JPEG round trip of pixels encoded a line before.
_DECODE_ALLOWED = {"loaders/image_gate.py", "loaders/synthetic/source_domain.py"}
_DECODERS = {"imdecode", "imread", "imreadmulti", "imdecodemulti", "imreadanimation", "imdecodeanimation"}


def test_no_image_is_decoded_outside_the_gate():
    """Every decode in the project goes through ``loaders.image_gate`` (tests may decode freely)."""
    bad = []
    for folder in ("loaders", "pipeline", "reports", "stages", "examples", "tools", "viewfuse"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                name = node.attr if isinstance(node, ast.Attribute) else \
                    node.name if isinstance(node, ast.alias) else None
                if name in _DECODERS and rel not in _DECODE_ALLOWED:
                    bad.append(f"{rel}:{node.lineno} {name}")
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    mods = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                    if any(m.split(".")[0] in ("PIL", "imageio", "skimage") for m in mods):
                        bad.append(f"{rel}:{node.lineno} imports an image library")
    assert not bad, "image decodes outside loaders/image_gate.py:\n" + "\n".join(bad)


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_mutated_headers_end_in_an_image_or_a_named_error(tmp_path, monkeypatch, name):
    """Seeded byte flips in the first 64 bytes (where every header sits) and random cuts: each
    ends in a decoded image no larger than its header declared, or a BadInputError naming the
    file; never another exception. The limit is lowered so an accepted header stays small."""
    from loaders import files
    monkeypatch.setitem(files._limit, "megapixels", 0.01)   # 10000 pixels: the fixtures are 2000
    rng = np.random.default_rng(sum(name.encode()))
    data = FIXTURES[name]
    p = tmp_path / "m.img"
    outcomes = {"decoded": 0, "refused": 0}
    for _ in range(40):
        b = bytearray(data)
        for at in rng.integers(0, min(64, len(b)), size=int(rng.integers(1, 4))):
            b[at] = int(rng.integers(0, 256))
        if rng.random() < 0.3:
            b = b[:int(rng.integers(1, len(b)))]
        try:
            img = decode_image(bytes(b), p)
        except BadInputError as e:
            assert e.path == str(p)
            outcomes["refused"] += 1
            continue
        assert img.shape[0] * img.shape[1] <= 10000
        outcomes["decoded"] += 1
    assert outcomes["refused"] > 0, outcomes


def test_jpeg_decodes_to_contiguous_rgb_in_the_file_s_channel_order(tmp_path):
    """decode_jpeg swaps OpenCV's BGR with cv2.cvtColor: red stays red, and the array is contiguous
    (torch.from_numpy and the crop path need it)."""
    import cv2

    from loaders.jpeg import decode_jpeg

    bgr = np.zeros((32, 48, 3), np.uint8)
    bgr[:, :16, 2] = 250   # red on the left, green in the middle, blue on the right (BGR order)
    bgr[:, 16:32, 1] = 250
    bgr[:, 32:, 0] = 250
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    rgb = decode_jpeg(buf.tobytes(), tmp_path / "x.jpg")
    assert rgb.flags.c_contiguous and rgb.dtype == np.uint8 and rgb.shape == (32, 48, 3)
    assert np.array_equal(rgb, cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1])
    assert rgb[16, 4].argmax() == 0 and rgb[16, 24].argmax() == 1 and rgb[16, 40].argmax() == 2
