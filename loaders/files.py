"""Dataset files are read as regular files inside their dataset root.

Every reader opens a dataset file through ``checked_file``: it must exist, be a regular file
(a FIFO would block the reader forever, ``/dev/zero`` would be read until memory runs out), and,
when the reader knows its dataset root, resolve (symlinks followed) to a path inside that root, so
a symlink cannot make a run read, and silently depend on, a file elsewhere. A refused file is a
``BadInputError`` naming it: counted as a skip or stopping the stage, per ``data.skip_bad_views``,
like any other bad entry.

``data.max_image_megapixels`` is held here; ``loaders.image_gate`` refuses an image whose header
declares more pixels before it is decoded (a 30000 x 30000 JPEG header costs seconds and
gigabytes to decode only to be skipped). ``read_checked`` stats a file before it reads it and
refuses one larger than any image within that limit can need (``max_file_bytes``): an 8 GB sparse
file named like a view is a named bad entry, not a MemoryError.
"""
from __future__ import annotations

import os
from pathlib import Path

from loaders.errors import BadInputError
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.decoder_limits import ENV as CAP_ENV, cap_megapixels
from pipeline.infra.cache import within
from pipeline.infra.filekind import not_regular

DEFAULT_MAX_MEGAPIXELS = 64.0  # real BigBIRD views are 1.3 MP (1280x1024), AVD images 2.1 MP
_limit = {"megapixels": DEFAULT_MAX_MEGAPIXELS}


# The most bytes one pixel takes in any format the gate admits (4 channels of 64-bit floats, TIFF),
# and what a file may hold beside its pixels (metadata: EXIF, ICC profiles, headers).
BYTES_PER_PIXEL = 32
METADATA_BYTES = 256 * 1024


def set_max_megapixels(mp: float) -> None:
    """The image size limit for this process (the runner sets ``data.max_image_megapixels``); a
    limit above OpenCV's own, fixed when it was loaded (``pipeline.infra.decoder_limits``), is a
    ConfigError: the decoder would refuse those images whatever the gate let through."""
    if float(mp) > cap_megapixels():
        raise ConfigError(f"data.max_image_megapixels = {mp:g} is above OpenCV's decoder limit for this process "
                          f"({cap_megapixels():g} MP, set before OpenCV was loaded); run with {CAP_ENV}={mp:g} "
                          f"in the environment to raise it")
    _limit["megapixels"] = float(mp)


def max_megapixels() -> float:
    return _limit["megapixels"]


def image_bytes_needed(pixels: float) -> int:
    """The most bytes an image of ``pixels`` pixels can need in any admitted format."""
    return int(pixels * BYTES_PER_PIXEL) + METADATA_BYTES


def max_file_bytes() -> int:
    """The largest dataset file read: what an image at ``data.max_image_megapixels`` can need."""
    return image_bytes_needed(max_megapixels() * 1e6)


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
        if not within(real, real_root):
            raise BadInputError(path, f"{what} resolves to {real}, outside the dataset root {root}; refused")
    return path


def read_checked(path: str | Path, root: str | Path | None = None, what: str = "file") -> bytes:
    """The bytes of a ``checked_file``; errors name the file. Its size is read first: a file larger
    than ``max_file_bytes`` is refused unread, and no more than its stat size (plus one byte, to
    see it grow) is ever read."""
    path = checked_file(path, root, what)
    cap = max_file_bytes()
    try:
        size = path.stat().st_size
        if size > cap:
            raise BadInputError(path, f"{what} is {size} bytes, more than any dataset file within "
                                      f"data.max_image_megapixels = {max_megapixels():g} can need ({cap} bytes); not read")
        with open(path, "rb") as f:
            data = f.read(size + 1)
    except OSError as e:
        raise BadInputError(path, f"cannot read {what} ({e.strerror or e})") from None
    if len(data) > size:
        raise BadInputError(path, f"{what} grew while it was read (stat said {size} bytes); refused")
    return data
