"""PBM (P4, raw 1-bit) masks as BigBIRD writes them.

BigBIRD polarity: object pixels are black, i.e. bit 1 in the packed raster (PBM's 1 = black);
here a decoded mask is a bool array with True = object. Real files put magic and size on one
line (``P4 1280 1024\\n``); the reader also accepts the standard multi-line header and comments.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from loaders.errors import BadInputError
from loaders.files import read_checked
from loaders.image_format import pnm_tokens
from loaders.image_gate import checked_image
from pipeline.infra.cache import note_read
from pipeline.infra.cache import write_bytes


def read_pbm(path: str | Path, root: str | Path | None = None) -> np.ndarray:
    """Decode a P4 mask: bool (H, W), True where the bit is 1 (black = object in BigBIRD). The file
    must be a regular file inside ``root`` (``loaders.files``)."""
    path = Path(path)
    data = read_checked(path, root, "mask file")
    note_read(path, data)
    _, w, h = checked_image(data, path, expect=("PBM",))  # before unpacking: 8 bytes per stored byte
    toks, off = pnm_tokens(data, 3)
    if toks[0] != b"P4":
        raise BadInputError(path, f"not a raw PBM (magic {toks[0][:8]!r}, expected b'P4')")
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
    write_bytes(path, encode_pbm(mask))
