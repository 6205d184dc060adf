"""JPEG decoding for every reader: completeness and corruption checks (libjpeg's warnings are
captured and turned into errors naming the file), decoding to RGB, and the frame size read from
the header without decoding."""
from __future__ import annotations

import contextlib
import os
import struct
import sys
import tempfile
import threading
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from loaders.errors import BadInputError
from loaders.files import SOF_MARKERS, check_image_size, checked_file, checked_header, read_checked
from pipeline.infra.cache import note_read


def check_jpeg_complete(data: bytes, path: Path) -> None:
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
# or garbage pixels; OpenCV passes neither the warning nor a status back. So the decode runs with
# file descriptor 2 redirected into a temporary file, and a warning there makes the image corrupt.
# "N extraneous bytes before marker" is left out: the decoder skipped padding between segments
# and the pixels are intact.
_STDERR_LOCK = threading.Lock()
_CORRUPT_MARKS = ("Corrupt JPEG data", "Premature end of JPEG file", "Inconsistent progression")


@contextlib.contextmanager
def c_stderr_captured() -> Iterator[list[str]]:
    """Collect what C code writes to file descriptor 2 meanwhile (lines go into the yielded list);
    lines that are not libjpeg messages are passed on to the real stderr afterwards."""
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
    other = [ln for ln in lines if not _is_jpeg_message(ln)]
    if other:
        os.write(2, ("\n".join(other) + "\n").encode())


def _is_jpeg_message(line: str) -> bool:
    return "JPEG" in line or "jpeg" in line or "marker" in line or "Huffman" in line


def _jpeg_problem(lines: list[str]) -> str | None:
    for ln in lines:
        if "extraneous bytes before marker" in ln:
            continue
        if any(m in ln for m in _CORRUPT_MARKS):
            return ln.strip()
    return None


def decode_jpeg(data: bytes, path: str | Path) -> np.ndarray:
    """Decode JPEG bytes into RGB uint8 (H, W, 3); BadInputError naming ``path`` when the file is
    truncated or libjpeg reports corrupt data."""
    path = Path(path)
    checked_header(data, path, "JPEG")  # the declared size, before anything is decoded
    check_jpeg_complete(data, path)
    with c_stderr_captured() as lines:
        try:
            bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        except cv2.error as e:
            raise BadInputError(path, f"corrupt JPEG: OpenCV failed to decode it ({e})") from None
    problem = _jpeg_problem(lines)
    if problem is not None:
        raise BadInputError(path, f"corrupt JPEG: libjpeg reports {problem!r}")
    if bgr is None or bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.size == 0:
        raise BadInputError(path, "corrupt JPEG: OpenCV could not decode it")
    return np.ascontiguousarray(bgr[:, :, ::-1])  # OpenCV gives BGR


def read_rgb(path: str | Path, root: str | Path | None = None) -> np.ndarray:
    """Decode a JPEG into RGB uint8 (H, W, 3); BadInputError naming the file if missing, corrupt,
    not a regular file inside ``root`` (``loaders.files``) or declaring too many pixels."""
    path = Path(path)
    data = read_checked(path, root, "image file")
    note_read(path, data)
    check_image_size(data, path)
    return decode_jpeg(data, path)


def jpeg_size(path: str | Path, root: str | Path | None = None) -> tuple[int, int]:
    """(width, height) from a JPEG's frame header, without decoding the image."""
    path = checked_file(path, root, "image file")
    try:
        f = open(path, "rb")
    except OSError as e:
        raise BadInputError(path, f"cannot read image file ({e.strerror or e})") from None
    with f:
        if f.read(2) != b"\xff\xd8":
            raise BadInputError(path, "not a JPEG (no SOI marker); file is corrupt")
        while True:
            b = f.read(1)
            if not b:
                break
            if b != b"\xff":
                continue  # tolerate garbage between segments, as decoders do
            m = f.read(1)
            while m == b"\xff":  # fill bytes
                m = f.read(1)
            if not m:
                break
            code = m[0]
            if code in (0x01,) or 0xD0 <= code <= 0xD8:
                continue  # stand-alone markers: no length field
            if code in (0xD9, 0xDA):
                break  # EOI / start of scan before any frame header
            seg = f.read(2)
            if len(seg) < 2:
                break
            (length,) = struct.unpack(">H", seg)
            if code in SOF_MARKERS:
                body = f.read(5)
                if len(body) < 5:
                    break
                h, w = struct.unpack(">HH", body[1:5])
                if w == 0 or h == 0:
                    raise BadInputError(path, f"corrupt JPEG: frame size {w}x{h}")
                return int(w), int(h)
            f.seek(length - 2, 1)
    raise BadInputError(path, "corrupt JPEG: no frame header (SOF marker) found")
