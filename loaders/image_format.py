"""An image's format and declared size, read from its first bytes without decoding (pure bytes
parsing; the gate that uses it is ``loaders.image_gate``).

``sniff`` names the format by its magic bytes, as OpenCV's decoders recognise them (bytes that
match two signatures are refused, so OpenCV's decoder order never matters). ``declared_size`` reads the (width, height)
the header declares, for every format this OpenCV build decodes by content: PNG, JPEG, WebP
(VP8, VP8L, VP8X), TIFF (both byte orders, BigTIFF; the first IFD, tiles included), PBM,
PGM, PPM (P1-P6), PAM, PFM, BMP, GIF (the screen and the first frame), JPEG 2000 (JP2 and raw
codestream: the SIZ marker), Radiance HDR, Sun raster and AVIF (its ``ispe`` properties). A
header that cannot be read raises ``HeaderError`` with the problem in words; the gate adds the
file's path. The size is the largest pixel area the decoder may be made to allocate, so a lie
between two size fields (a TIFF tile larger than its image) counts the larger.
"""
from __future__ import annotations

import re
import struct


class HeaderError(ValueError):
    """The header is missing, truncated or inconsistent (the message says how)."""


# SOFn markers carry the frame size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}

def _is_avif(data: bytes) -> bool:
    size = _u32(data, 0, ">")
    return data[4:8] == b"ftyp" and re.search(rb"avi[fs]", data[8:max(16, min(len(data), size))]) is not None


# (format, test of the first bytes): the signatures OpenCV's decoders check
_SIGNATURES = (
    ("PNG", lambda d: d[:8] == b"\x89PNG\r\n\x1a\n"),
    ("JPEG", lambda d: d[:3] == b"\xff\xd8\xff"),
    ("WebP", lambda d: d[:4] == b"RIFF" and d[8:12] == b"WEBP"),
    ("TIFF", lambda d: d[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")),
    ("PBM", lambda d: d[:2] in (b"P1", b"P4") and d[2:3].isspace()),
    ("PGM", lambda d: d[:2] in (b"P2", b"P5") and d[2:3].isspace()),
    ("PPM", lambda d: d[:2] in (b"P3", b"P6") and d[2:3].isspace()),
    ("PAM", lambda d: d[:2] == b"P7" and d[2:3].isspace()),
    ("PFM", lambda d: d[:2] in (b"PF", b"Pf") and d[2:3].isspace()),
    ("BMP", lambda d: d[:2] == b"BM"),
    ("GIF", lambda d: d[:6] in (b"GIF87a", b"GIF89a")),
    ("JPEG 2000", lambda d: d[:12] == b"\x00\x00\x00\x0cjP  \r\n\x87\n" or d[:4] == b"\xff\x4f\xff\x51"),
    ("HDR", lambda d: d[:6] == b"#?RGBE" or d[:10] == b"#?RADIANCE"),
    ("Sun raster", lambda d: d[:4] == b"\x59\xa6\x6a\x95"),
    ("AVIF", _is_avif),
)


def signatures(data: bytes) -> list[str]:
    """Every format whose signature the first bytes match (one for any real image: the gate
    refuses bytes that match several, as OpenCV's choice would then depend on its decoder order)."""
    return [name for name, test in _SIGNATURES if test(data)]


def sniff(data: bytes) -> str | None:
    """The one format the magic bytes identify, or None (no format, or several)."""
    found = signatures(data)
    return found[0] if len(found) == 1 else None


def declared_size(data: bytes, fmt: str) -> tuple[int, int]:
    """(width, height) the header of a ``fmt`` image declares; HeaderError when it cannot be read."""
    try:
        return _READERS[fmt](data)
    except (struct.error, IndexError, ValueError) as e:
        if isinstance(e, HeaderError):
            raise
        raise HeaderError(f"truncated or malformed {fmt} header ({e})") from None


def _u32(data: bytes, at: int, order: str) -> int:
    return struct.unpack_from(order + "I", data, at)[0] if len(data) >= at + 4 else 0


def _png(data: bytes) -> tuple[int, int]:
    if data[12:16] != b"IHDR":
        raise HeaderError("no header declaring the image size (IHDR chunk) found")
    return struct.unpack_from(">II", data, 16)


def _jpeg(data: bytes) -> tuple[int, int]:
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            i += 1  # tolerate garbage between segments, as decoders do
            continue
        code = data[i + 1]
        if code == 0xFF:  # fill byte
            i += 1
            continue
        if code == 0x01 or 0xD0 <= code <= 0xD8:
            i += 2  # stand-alone markers: no length field
            continue
        if code in (0xD9, 0xDA):
            break  # end of image / start of scan before any frame header
        (length,) = struct.unpack_from(">H", data, i + 2)
        if code in SOF_MARKERS:
            h, w = struct.unpack_from(">HH", data, i + 5)
            return w, h
        i += 2 + length
    raise HeaderError("no header declaring the image size (SOF marker) found")


def _webp(data: bytes) -> tuple[int, int]:
    kind = data[12:16]
    if kind == b"VP8X":  # extended: the canvas, 24-bit minus-one fields
        if len(data) < 30:
            raise HeaderError("truncated VP8X chunk")
        return int.from_bytes(data[24:27], "little") + 1, int.from_bytes(data[27:30], "little") + 1
    if kind == b"VP8L":  # lossless: signature 0x2f, then two 14-bit minus-one fields
        if data[20] != 0x2F:
            raise HeaderError("VP8L chunk without its signature byte")
        bits = struct.unpack_from("<I", data, 21)[0]
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8 ":  # lossy: 3-byte frame tag, start code, 14-bit fields (2 bits of scale)
        if data[23:26] != b"\x9d\x01\x2a":
            raise HeaderError("VP8 chunk without its start code")
        w, h = struct.unpack_from("<HH", data, 26)
        return w & 0x3FFF, h & 0x3FFF
    raise HeaderError(f"unknown WebP chunk {bytes(kind)!r} where VP8/VP8L/VP8X belongs")


def _tiff(data: bytes) -> tuple[int, int]:
    o = "<" if data[:2] == b"II" else ">"
    big = data[2:4] in (b"+\x00", b"\x00+")
    ifd = struct.unpack_from(o + "Q", data, 8)[0] if big else struct.unpack_from(o + "I", data, 4)[0]
    count = struct.unpack_from(o + ("Q" if big else "H"), data, ifd)[0]
    first, size = ifd + (8 if big else 2), 20 if big else 12
    if first + count * size > len(data):
        raise HeaderError(f"first IFD at byte {ifd} with {count} entries runs past the end of the file")
    tags = {}
    for k in range(count):
        at = first + k * size
        tag, typ = struct.unpack_from(o + "HH", data, at)
        fmt = {3: "H", 4: "I", 16: "Q"}.get(typ)
        if fmt is not None and tag in (256, 257, 322, 323):  # width, length, tile width/length
            tags[tag] = struct.unpack_from(o + fmt, data, at + (12 if big else 8))[0]
    if 256 not in tags or 257 not in tags:
        raise HeaderError("first IFD declares no ImageWidth/ImageLength")
    w, h = tags[256], tags[257]
    tw, th = tags.get(322, 0), tags.get(323, 0)
    if tw * th > w * h:  # the decoder allocates a whole tile
        raise HeaderError(f"declares {tw}x{th} tiles in a {w}x{h} image")
    return w, h


def pnm_tokens(data: bytes, n: int) -> tuple[list[bytes], int]:
    """The first ``n`` whitespace-separated header tokens of a PNM/PFM file (``#`` comments
    skipped) and the byte offset just after the single whitespace byte that ends them."""
    toks: list[bytes] = []
    i, end = 0, len(data)
    while len(toks) < n:
        while i < end and data[i:i + 1].isspace():
            i += 1
        if i < end and data[i:i + 1] == b"#":
            while i < end and data[i:i + 1] not in (b"\n", b"\r"):
                i += 1
            continue
        j = i
        while j < end and not data[j:j + 1].isspace() and data[j:j + 1] != b"#":
            j += 1
        if j == i:
            raise HeaderError("truncated header")
        toks.append(data[i:j])
        i = j
    if i >= end or not data[i:i + 1].isspace():
        raise HeaderError("header not followed by a single whitespace byte")
    return toks, i + 1


def _ints(fields: list[bytes]) -> tuple[int, int]:
    if not all(re.fullmatch(rb"[0-9]{1,12}", f) for f in fields):
        raise HeaderError(f"bad size {b' x '.join(fields)[:40]!r}")
    return int(fields[0]), int(fields[1])


def _pnm(data: bytes) -> tuple[int, int]:
    return _ints(pnm_tokens(data, 3)[0][1:3])


def _pam(data: bytes) -> tuple[int, int]:
    head = data[:data.find(b"ENDHDR")] if b"ENDHDR" in data[:4096] else b""
    if not head:
        raise HeaderError("no ENDHDR line in the first 4096 bytes")
    w = re.search(rb"^WIDTH\s+(\S+)", head, re.M)
    h = re.search(rb"^HEIGHT\s+(\S+)", head, re.M)
    if w is None or h is None:
        raise HeaderError("no WIDTH/HEIGHT line")
    return _ints([w.group(1), h.group(1)])


def _bmp(data: bytes) -> tuple[int, int]:
    dib = _u32(data, 14, "<")
    if dib == 12:  # OS/2 core header: unsigned 16-bit fields
        return struct.unpack_from("<HH", data, 18)
    if dib < 40:
        raise HeaderError(f"unknown DIB header size {dib}")
    w, h = struct.unpack_from("<ii", data, 18)
    return w, abs(h)  # a negative height means top-down rows


def _gif(data: bytes) -> tuple[int, int]:
    sw, sh = struct.unpack_from("<HH", data, 6)
    if not sw or not sh:
        return sw, sh  # an empty screen is refused whatever its frames say
    i = 13 + (3 << ((data[10] & 7) + 1) if data[10] & 0x80 else 0)
    while i < len(data):
        kind = data[i]
        if kind == 0x2C:  # the first frame: it may reach outside the screen
            left, top, fw, fh = struct.unpack_from("<HHHH", data, i + 1)
            return max(sw, left + fw), max(sh, top + fh)
        if kind != 0x21:
            break
        i += 2  # extension introducer and label, then sub-blocks up to a zero length
        while i < len(data) and data[i]:
            i += data[i] + 1
        i += 1
    raise HeaderError("no image descriptor found")


def _j2k_siz(data: bytes, at: int) -> tuple[int, int]:
    if data[at:at + 4] != b"\xff\x4f\xff\x51":
        raise HeaderError("codestream does not start with SOC and SIZ markers")
    xs, ys, xo, yo, tx, ty, txo, tyo = struct.unpack_from(">8I", data, at + 8)
    if xo >= xs or yo >= ys:
        raise HeaderError(f"image offset {xo},{yo} outside the reference grid {xs}x{ys}")
    if tx * ty > (xs - xo) * (ys - yo):
        raise HeaderError(f"declares {tx}x{ty} tiles in a {xs - xo}x{ys - yo} image")
    return xs - xo, ys - yo


def _jpeg2000(data: bytes) -> tuple[int, int]:
    if data[:4] == b"\xff\x4f\xff\x51":
        return _j2k_siz(data, 0)
    for kind, start, _ in _boxes(data, 0, len(data)):  # JP2: the codestream is the jp2c box
        if kind == b"jp2c":
            return _j2k_siz(data, start)
    raise HeaderError("no codestream (jp2c box) found")


def _boxes(data: bytes, at: int, end: int):
    """(type, payload start, payload end) of the ISO boxes in data[at:end]."""
    while at + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, at)
        head = 8
        if size == 1:
            size, head = struct.unpack_from(">Q", data, at + 8)[0], 16
        elif size == 0:
            size = end - at
        if size < head or at + size > end:
            raise HeaderError(f"box {kind!r} at byte {at} declares {size} bytes, past its container")
        yield kind, at + head, at + size
        at += size


def _avif_size(data: bytes) -> tuple[int, int]:
    sizes = []

    def walk(at: int, end: int) -> None:
        for kind, start, stop in _boxes(data, at, end):
            if kind == b"meta":
                walk(start + 4, stop)  # a full box: version and flags first
            elif kind in (b"iprp", b"ipco"):
                walk(start, stop)
            elif kind == b"ispe":
                sizes.append(struct.unpack_from(">II", data, start + 4))
    walk(0, len(data))
    if not sizes:
        raise HeaderError("no image size property (ispe) found")
    return max(sizes, key=lambda s: s[0] * s[1])


def _hdr(data: bytes) -> tuple[int, int]:
    blank = data.find(b"\n\n", 0, 65536)
    if blank < 0:
        raise HeaderError("no end of header (blank line) in the first 64 KiB")
    line = data[blank + 2:blank + 2 + 64].split(b"\n", 1)[0]
    m = re.fullmatch(rb"([-+])([XY]) ([0-9]{1,9}) ([-+])([XY]) ([0-9]{1,9})", line.strip())
    if m is None or m.group(2) == m.group(5):
        raise HeaderError(f"bad resolution line {line[:40]!r}")
    size = {m.group(2): int(m.group(3)), m.group(5): int(m.group(6))}
    return size[b"X"], size[b"Y"]


def _sun(data: bytes) -> tuple[int, int]:
    return struct.unpack_from(">II", data, 4)


_READERS = {"PNG": _png, "JPEG": _jpeg, "WebP": _webp, "TIFF": _tiff, "PBM": _pnm, "PGM": _pnm, "PPM": _pnm,
            "PAM": _pam, "PFM": _pnm, "BMP": _bmp, "GIF": _gif, "JPEG 2000": _jpeg2000, "HDR": _hdr,
            "Sun raster": _sun, "AVIF": _avif_size}
