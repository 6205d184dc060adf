"""The one image gate: every image a reader decodes passes ``checked_image`` first, and every
OpenCV decode is ``decode_image``.

``checked_image`` names the format by its magic bytes (``loaders.image_format``), reads the size
its header declares and refuses it above ``data.max_image_megapixels`` before anything is
decoded; an empty file, bytes of no format it can size (whatever the file's name says), a header
that cannot be read and a format the reader does not expect are refused as well. So OpenCV is only
ever handed bytes whose size is known, whichever of its decoders would have recognised them.

``decode_image`` then decodes and turns every decoder failure into a ``BadInputError`` naming the
file (a counted skip under ``data.skip_bad_views``): a None return, a ``cv2.error``, libjpeg's
corruption warnings (printed on the C-level stderr only, with grey pixels returned) and a decoded
image larger than its header declared. Two bounds do not depend on the gate reading the header as
the decoder does: OpenCV's own size limits, set before it was loaded
(``pipeline.infra.decoder_limits``; ``decoder_limits_active`` checks they hold), and the file's
byte count against what its declared size can need (``loaders.files.image_bytes_needed``), which
also bounds the decompression work a small declared image can ask for (a 1 x 1 PNG with a
30000² IDAT stream).
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from loaders.errors import BadInputError
from loaders.files import image_bytes_needed, max_megapixels, read_checked
from pipeline.infra.decoder_limits import MAX_SIDE
from loaders.image_format import HeaderError, declared_size, signatures


def check_declared(w: int, h: int, path: str | Path) -> None:
    """BadInputError when a header's ``w`` x ``h`` is empty or above ``data.max_image_megapixels``."""
    if w <= 0 or h <= 0:
        raise BadInputError(path, f"image declares {w}x{h} pixels; corrupt header, not decoded")
    mp = w * h / 1e6
    if mp > max_megapixels():
        raise BadInputError(path, f"image declares {w}x{h} pixels ({mp:.0f} MP), above the limit "
                                  f"data.max_image_megapixels = {max_megapixels():g}; not decoded")


def checked_image(data: bytes, path: str | Path, expect: tuple[str, ...] | None = None) -> tuple[str, int, int]:
    """(format, width, height) of image bytes whose header declares a size within the limit;
    BadInputError naming ``path`` otherwise, or when the format is not one of ``expect``."""
    wanted = " or ".join(expect) if expect else "an image"
    if not data:
        raise BadInputError(path, f"empty file (0 bytes), not {_article(wanted)}")
    found = signatures(data)
    if len(found) > 1:  # OpenCV's decoder order would decide which header counts
        raise BadInputError(path, f"bytes match the signatures of {' and '.join(found)}; ambiguous, not decoded")
    fmt = found[0] if found else None
    if fmt is None:
        what = f"not {_article(wanted)} (no {wanted} signature)" if expect else \
            "not an image format whose size can be read before decoding"
        raise BadInputError(path, f"{what}; file is corrupt, not decoded (first bytes {data[:8]!r})")
    try:
        w, h = declared_size(data, fmt)
    except HeaderError as e:
        raise BadInputError(path, f"corrupt {fmt}: {e}; not decoded") from None
    check_declared(w, h, path)
    need = image_bytes_needed(w * h)
    if len(data) > need:
        raise BadInputError(path, f"{fmt} file holds {len(data)} bytes, more than the {w}x{h} pixels its header "
                                  f"declares can need ({need} bytes); not decoded (a compressed stream that large "
                                  f"would decompress far beyond the image)")
    if expect and fmt not in expect:
        raise BadInputError(path, f"not {_article(wanted)}: the content is {fmt}; refused")
    if fmt == "JPEG":
        check_jpeg_complete(data, path)
    return fmt, w, h


def _article(name: str) -> str:
    return name if name == "an image" else ("an " if name[:1] in "AEIOU" else "a ") + name


def decode_image(data: bytes, path: str | Path, flag: int = cv2.IMREAD_COLOR,
                 expect: tuple[str, ...] | None = None) -> np.ndarray:
    """OpenCV's decode (BGR order, as ``cv2.imdecode`` gives it) of bytes that passed
    ``checked_image``; every decoder failure is a BadInputError naming ``path``."""
    path = Path(path)
    fmt, w, h = checked_image(data, path, expect)
    if not decoder_limits_active():
        warnings.warn("OpenCV was loaded before viewfuse's pipeline package, so its decoder size limits "
                      "(OPENCV_IO_MAX_IMAGE_PIXELS) are its defaults: load viewfuse (or its pipeline package) before cv2",
                      RuntimeWarning, stacklevel=2)
    failure = None
    with c_stderr_captured(echo=False) as lines:
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), flag)
        except cv2.error as e:  # OpenCV asserts on some inputs instead of returning None
            # str(e), not e.err: OpenCV's bindings set err on the exception type, so it holds the
            # last error OpenCV raised anywhere in the process, not necessarily this one
            said = str(e).strip()
            said = said[said.find("(-"):] if "(-" in said else said
            img, failure = None, (f"OpenCV's decoder reads a size above its limit ({said}), though the header as "
                                  f"read before decoding declares {w}x{h}: the header is ambiguous" if
                                  "CV_IO_MAX_IMAGE" in said else f"OpenCV failed to decode it ({said})")
    problem = _jpeg_problem(lines) if fmt == "JPEG" else None
    if problem is not None:
        raise BadInputError(path, f"corrupt JPEG: libjpeg reports {problem!r}")
    if failure is None and (img is None or img.size == 0):
        said = _opencv_said(lines)
        failure = "OpenCV could not decode it" + (f" ({said})" if said else "")
    if failure is not None:
        raise BadInputError(path, f"corrupt {fmt}: {failure}")
    _echo([ln for ln in lines if not _is_jpeg_message(ln)])
    if img.shape[0] * img.shape[1] > w * h:
        raise BadInputError(path, f"decoded {img.shape[1]}x{img.shape[0]} pixels, more than the "
                                  f"{w}x{h} its {fmt} header declares; refused")
    return img


@lru_cache(maxsize=1)
def decoder_limits_active() -> bool:
    """Whether OpenCV refuses a size above ``decoder_limits.MAX_SIDE`` itself: a PGM header
    declaring one row that wide (no pixel data; nothing is allocated when the limit holds)."""
    probe = f"P5\n{MAX_SIDE + 1} 1\n255\n".encode()
    with c_stderr_captured(echo=False):
        try:
            cv2.imdecode(np.frombuffer(probe, np.uint8), cv2.IMREAD_GRAYSCALE)
        except cv2.error:
            return True
    return False


def read_rgb(path: str | Path) -> np.ndarray:
    """An image file as a contiguous RGB array, through the gate (format and declared size checked
    before decoding); an unreadable or corrupt file is a BadInputError naming it. For code outside
    the stages that reads images (a dataset source's reader, an example)."""
    path = Path(path)
    data = read_checked(path, None, "image file")
    return cv2.cvtColor(decode_image(data, path), cv2.COLOR_BGR2RGB)


def check_jpeg_complete(data: bytes, path: str | Path) -> None:
    """OpenCV decodes a truncated JPEG into a grey-padded image with only a warning, so check the
    markers ourselves: SOI first, and an EOI after the first scan (SOS). Entropy-coded data
    byte-stuffs 0xFF, so FF D9 after SOS can only be the real end marker (EXIF thumbnails, which
    carry their own EOI, sit before the first SOS)."""
    if data[:2] != b"\xff\xd8":
        raise BadInputError(path, "not a JPEG (no SOI marker); file is corrupt")
    sos = data.find(b"\xff\xda", 2)
    if sos < 0:
        raise BadInputError(path, "corrupt JPEG: no image scan (SOS marker) found")
    if data.find(b"\xff\xd9", sos) < 0:
        raise BadInputError(path, "corrupt JPEG: truncated (no end-of-image marker after the scan)")


# libjpeg reports damaged entropy-coded data ("Corrupt JPEG data: premature end of data
# segment", bad Huffman codes) only as a warning printed on the C-level stderr, then returns grey
# or garbage pixels; OpenCV passes neither the warning nor a status back, and logs its own decode
# failures there too. So a decode runs with file descriptor 2 redirected into a temporary file.
# "N extraneous bytes before marker" is left out: the decoder skipped padding between segments
# and the pixels are intact.
_STDERR_LOCK = threading.Lock()
_CORRUPT_MARKS = ("Corrupt JPEG data", "Premature end of JPEG file", "Inconsistent progression")


@contextlib.contextmanager
def c_stderr_captured(echo: bool = True) -> Iterator[list[str]]:
    """Collect what C code writes to file descriptor 2 meanwhile (lines go into the yielded list);
    with ``echo``, lines that are not libjpeg messages are passed on to the real stderr afterwards."""
    lines: list[str] = []
    with _STDERR_LOCK:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError):
            pass
        try:
            saved = os.dup(2)
        except OSError:  # no stderr at all (closed descriptor): nothing to capture from
            yield lines
            return
        try:
            with tempfile.TemporaryFile() as tf:
                os.dup2(tf.fileno(), 2)
                try:
                    yield lines
                finally:
                    os.dup2(saved, 2)
                    tf.seek(0)
                    text = tf.read().decode("utf-8", "replace")
                    lines.extend(ln for ln in text.splitlines() if ln.strip())
        finally:
            os.close(saved)
    if echo:
        _echo([ln for ln in lines if not _is_jpeg_message(ln)])


def _echo(lines: list[str]) -> None:
    if lines:
        os.write(2, ("\n".join(lines) + "\n").encode())


def _is_jpeg_message(line: str) -> bool:
    return "JPEG" in line or "jpeg" in line or "marker" in line or "Huffman" in line


def _jpeg_problem(lines: list[str]) -> str | None:
    for ln in lines:
        if "extraneous bytes before marker" in ln:
            continue
        if any(m in ln for m in _CORRUPT_MARKS):
            return ln.strip()
    return None


_LOG_PREFIX = re.compile(r"^\[\s*\w+:[^\]]*\]\s*(global\s+\S+\s+\S+\s+)?(imdecode_\(''\):\s*)?")


def _opencv_said(lines: list[str]) -> str:
    """OpenCV's first logged line about the failure, without its log prefix and source paths."""
    for ln in lines:
        if ln.startswith("["):
            text = _LOG_PREFIX.sub("", ln)
            text = re.sub(r"OpenCV\([^)]*\) \S+: error: \([^)]*\)\s*", "", text)
            return text.strip()[:200]
    return ""
