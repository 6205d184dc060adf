"""JPEG reading for the BigBIRD and AVD readers: decoding to RGB through the image gate
(``loaders.image_gate``: size limit, completeness, libjpeg's corruption warnings), and the frame
size read from the header without reading the whole file."""
from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from loaders.errors import BadInputError
from loaders.files import checked_file, read_checked
from loaders.image_format import SOF_MARKERS
from loaders.image_gate import decode_image
from pipeline.infra.cache import note_read


def decode_jpeg(data: bytes, path: str | Path) -> np.ndarray:
    """Decode JPEG bytes into RGB uint8 (H, W, 3) through the image gate; BadInputError naming
    ``path`` for another format, a size above the limit, a truncated file or corrupt data."""
    bgr = decode_image(data, path, cv2.IMREAD_COLOR, expect=("JPEG",))
    if bgr.ndim != 3 or bgr.shape[2] != 3:
        raise BadInputError(path, f"corrupt JPEG: decoded to shape {bgr.shape}, not colour")
    # OpenCV gives BGR; its channel swap is exact and ~8x cheaper than numpy's reversed-stride copy
    # of a full frame (the features stage decodes one per AVD frame)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_rgb(path: str | Path, root: str | Path | None = None) -> np.ndarray:
    """Decode a JPEG into RGB uint8 (H, W, 3); BadInputError naming the file if missing, corrupt,
    not a regular file inside ``root`` (``loaders.files``) or declaring too many pixels."""
    path = Path(path)
    data = read_checked(path, root, "image file")
    note_read(path, data)
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
