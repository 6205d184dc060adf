"""Dataset files are read as regular files inside their dataset root.

Every reader opens a dataset file through ``checked_file``: it must exist, be a regular file
(a FIFO would block the reader forever, ``/dev/zero`` would be read until memory runs out), and,
when the reader knows its dataset root, resolve (symlinks followed) to a path inside that root, so
a symlink cannot make a run read, and silently depend on, a file elsewhere. A refused file is a
``BadInputError`` naming it: counted as a skip or stopping the stage, per ``data.skip_bad_views``,
like any other bad entry.

``check_image_size`` refuses an image whose header declares more pixels than
``data.max_image_megapixels`` before it is decoded (a 30000 x 30000 JPEG header costs seconds and
gigabytes to decode only to be skipped).
"""
from __future__ import annotations

import os
import struct
from pathlib import Path

from loaders.errors import BadInputError
from pipeline.infra.filekind import not_regular

DEFAULT_MAX_MEGAPIXELS = 64.0  # real BigBIRD views are 1.3 MP (1280x1024), AVD images 2.1 MP
_limit = {"megapixels": DEFAULT_MAX_MEGAPIXELS}


def set_max_megapixels(mp: float) -> None:
    """The image size limit for this process (the runner sets ``data.max_image_megapixels``)."""
    _limit["megapixels"] = float(mp)


def max_megapixels() -> float:
    return _limit["megapixels"]


def plain_name(name, source: str | Path, what: str = "name") -> str:
    """``name`` if it is one plain file name (a dataset file's image key, instance name or scan
    folder): a non-empty string without '/', '\\', NUL, and not '.' or '..'; a name that could
    lead a reader or a writer out of its folder is a BadInputError naming ``source``."""
    if not isinstance(name, str) or not name:
        raise BadInputError(source, f"{what} {name!r} is not a non-empty string; refused")
    bad = next((c for c in ("/", "\\", "\0") if c in name), None)
    if bad is not None or name in (".", "..") or os.path.isabs(name):
        why = f"contains {bad!r}" if bad else "is a path, not a file name"
        raise BadInputError(source, f"{what} {name!r} {why} (a plain file name is required); refused")
    return name


def checked_file(path: str | Path, root: str | Path | None = None, what: str = "file") -> Path:
    """``path`` if it is a regular file (symlinks followed) inside ``root``; BadInputError naming it
    otherwise. Only ``stat`` is called, never ``open``, so a FIFO cannot block here."""
    path = Path(path)
    problem = not_regular(path, what)
    if problem is not None:
        raise BadInputError(path, problem[1])
    if root is not None:
        real, real_root = os.path.realpath(path), os.path.realpath(root)
        if os.path.commonpath([real, real_root]) != real_root:
            raise BadInputError(path, f"{what} resolves to {real}, outside the dataset root {root}; refused")
    return path


def read_checked(path: str | Path, root: str | Path | None = None, what: str = "file") -> bytes:
    """The bytes of a ``checked_file``; errors name the file."""
    path = checked_file(path, root, what)
    try:
        return path.read_bytes()
    except OSError as e:
        raise BadInputError(path, f"cannot read {what} ({e.strerror or e})") from None


# SOFn markers carry the frame size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def declared_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) a JPEG's frame header or a PNG's IHDR declares, read without decoding;
    None when the header is not found (the decoder then reports the file as corrupt)."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR" and len(data) >= 24:
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] != b"\xff\xd8":
        return None
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
            return None  # end of image / start of scan before any frame header
        (length,) = struct.unpack(">H", data[i + 2:i + 4])
        if code in SOF_MARKERS:
            if i + 9 > n:
                return None
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return int(w), int(h)
        i += 2 + length
    return None


def check_declared(w: int, h: int, path: str | Path) -> None:
    """BadInputError when a header's ``w`` x ``h`` is empty or above ``data.max_image_megapixels``."""
    if w <= 0 or h <= 0:
        raise BadInputError(path, f"image declares {w}x{h} pixels; corrupt header, not decoded")
    mp = w * h / 1e6
    if mp > max_megapixels():
        raise BadInputError(path, f"image declares {w}x{h} pixels ({mp:.0f} MP), above the limit "
                                  f"data.max_image_megapixels = {max_megapixels():g}; not decoded")


def check_image_size(data: bytes, path: str | Path) -> None:
    """BadInputError when the image's header declares more than ``data.max_image_megapixels``."""
    size = declared_size(data)
    if size is not None:
        check_declared(*size, path)


def checked_header(data: bytes, path: str | Path, kind: str) -> tuple[int, int]:
    """(width, height) of a ``kind`` ('PNG' or 'JPEG') file's header, checked against the size
    limit; BadInputError for an empty file, another format or a missing header: a decoder is only
    handed bytes whose size it has been told to expect."""
    if not data:
        raise BadInputError(path, f"empty file (0 bytes), not a {kind}")
    magic = {"PNG": b"\x89PNG\r\n\x1a\n", "JPEG": b"\xff\xd8"}[kind]
    if data[:len(magic)] != magic:
        raise BadInputError(path, f"not a {kind} (no {kind} signature); file is corrupt")
    size = declared_size(data)
    if size is None:
        raise BadInputError(path, f"corrupt {kind}: no header declaring the image size "
                                  f"({'IHDR' if kind == 'PNG' else 'SOF marker'}) found")
    check_declared(*size, path)
    return size
