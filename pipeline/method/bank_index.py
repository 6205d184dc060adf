"""The JSON index of a model bank folder (GP banks: ``gp_files.py``; the banks of methods'
own models that use it): one reader that checks it before anything trusts it, one writer that merges a
caller's extra keys without letting them overwrite the bank's own; and the one content
digest of a bank or any part of one (``content_digest``)."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from pipeline.infra.cache import within, write_json
from pipeline.infra.outputs import ArtifactError, read_json


def content_digest(*parts) -> str:
    """The one content digest of model-bank contents (GP banks, one GP of one, a method's own models):
    blake2b-128, hex, over the parts in order, an array by its dtype, shape and bytes, anything
    else by its canonical JSON. It keys the in-process caches that must not serve other models
    under the same names and a provider's check of its saved parameters."""
    h = hashlib.blake2b(digest_size=16)
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"array {a.dtype.str} {a.shape}\n".encode())
            h.update(a.tobytes())
        else:
            h.update(f"json {json.dumps(p, sort_keys=True, separators=(',', ':'))}\n".encode())
    return h.hexdigest()


def read_index(ipath: Path, fmt: str, version: int, keys: tuple[str, ...], error, what: str) -> dict:
    """index.json at ``ipath`` as a dict with format ``fmt``, version ``version`` and ``keys``;
    else ``error(path, problem)`` naming the file (``what``: e.g. "model index")."""
    if not ipath.is_file():
        raise error(ipath, f"{what} not found (run the 'models' stage)")
    try:
        index = read_json(ipath)
    except ArtifactError as e:
        raise error(ipath, e.problem) from None
    if not isinstance(index, dict) or index.get("format") != fmt:
        got = index.get("format") if isinstance(index, dict) else None
        raise error(ipath, f"not a viewfuse {what} (format {got!r}, expected {fmt!r})")
    if index.get("version") != version:
        raise error(ipath, f"unsupported {what} version {index.get('version')!r} (expected {version})")
    for key in keys:
        if key not in index:
            raise error(ipath, f"missing key '{key}'")
    return index


def write_index(path: Path, index: dict, extra: dict | None) -> Path:
    """Write ``index`` plus ``extra`` (whose keys may not overwrite the index's) to ``path``."""
    out = dict(index)
    for k, v in (extra or {}).items():
        if k in out:
            raise ValueError(f"save: extra key {k!r} would overwrite a reserved index key")
        out[k] = v
    write_json(path, out)
    return path


def inside(folder: Path, rel, ipath: Path, error, what: str) -> Path:
    """``folder / rel`` for a path an index names, if ``rel`` is a relative path that stays, symlinks
    followed, inside ``folder``; else ``error(ipath, problem)``. An index is a file in a run folder,
    so an absolute or ``../..`` entry would make a stage load (and depend on) files elsewhere. The
    folder itself may be a link (a run's ``models/`` linked to another run's)."""
    if not isinstance(rel, str) or not rel or "\x00" in rel:
        raise error(ipath, f"{what} must be a relative path, got {rel!r:.80}")
    if os.path.isabs(rel):
        raise error(ipath, f"{what} {rel!r:.80} is an absolute path; an index names files inside its own folder")
    real_folder = os.path.realpath(folder)
    real = os.path.realpath(os.path.join(real_folder, rel))
    if real == real_folder or not within(real, real_folder):
        raise error(ipath, f"{what} {rel!r:.80} resolves to {real}, outside {folder}; refused")
    return Path(folder) / rel
