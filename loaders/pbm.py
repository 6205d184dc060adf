"""PBM (P4, raw 1-bit) masks as BigBIRD writes them.

BigBIRD polarity: object pixels are black, i.e. bit 1 in the packed raster (PBM's 1 = black);
here a decoded mask is a bool array with True = object. Real files put magic and size on one
line (``P4 1280 1024\\n``); the reader also accepts the standard multi-line header and comments.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from loaders.errors import BadInputError
from loaders.files import check_declared, read_checked
from pipeline.infra.cache import note_read


def _tokens(data: bytes, path: Path) -> tuple[list[bytes], int]:
    """The three header tokens (magic, width, height) and the raster's byte offset."""
    toks: list[bytes] = []
    i, n = 0, len(data)
    while len(toks) < 3:
        while i < n and data[i:i + 1].isspace():
            i += 1
        if i < n and data[i:i + 1] == b"#":
            while i < n and data[i:i + 1] not in (b"\n", b"\r"):
                i += 1
            continue
        j = i
        while j < n and not data[j:j + 1].isspace() and data[j:j + 1] != b"#":
            j += 1
        if j == i:
            raise BadInputError(path, "truncated PBM header")
        toks.append(data[i:j])
        i = j
    if i >= n or not data[i:i + 1].isspace():
        raise BadInputError(path, "PBM header not followed by a single whitespace byte")
    return toks, i + 1


def read_pbm(path: str | Path, root: str | Path | None = None) -> np.ndarray:
    """Decode a P4 mask: bool (H, W), True where the bit is 1 (black = object in BigBIRD). The file
    must be a regular file inside ``root`` (``loaders.files``)."""
    path = Path(path)
    data = read_checked(path, root, "mask file")
    note_read(path, data)
    toks, off = _tokens(data, path)
    if toks[0] != b"P4":
        raise BadInputError(path, f"not a raw PBM (magic {toks[0][:8]!r}, expected b'P4')")
    try:
        w, h = int(toks[1]), int(toks[2])
    except ValueError:
        raise BadInputError(path, f"bad PBM size {toks[1]!r} x {toks[2]!r}") from None
    if w <= 0 or h <= 0:
        raise BadInputError(path, f"bad PBM size {w} x {h}")
    check_declared(w, h, path)  # before the raster is unpacked (8 bytes per stored byte)
    row = (w + 7) // 8
    raster = np.frombuffer(data, dtype=np.uint8, count=len(data) - off, offset=off)
    if raster.size < row * h:
        raise BadInputError(path, f"PBM raster truncated: {raster.size} bytes, expected {row * h} for {w}x{h}")
    bits = np.unpackbits(raster[: row * h].reshape(h, row), axis=1)[:, :w]
    return bits.astype(bool)


def encode_pbm(mask: np.ndarray) -> bytes:
    """Encode a bool mask (True = object = black = bit 1) with BigBIRD's one-line header."""
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    h, w = mask.shape
    return f"P4 {w} {h}\n".encode() + np.packbits(mask, axis=1).tobytes()


def write_pbm(path: str | Path, mask: np.ndarray) -> None:
    from pipeline.infra.cache import write_bytes
    write_bytes(path, encode_pbm(mask))
