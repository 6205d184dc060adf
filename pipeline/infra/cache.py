"""Content hashes and atomic writes: the pieces stage manifests are built from.

The one home of sha256 (of bytes, files, JSON, file trees, and a running digest built piece by
piece: ``sha256_stream``); digests of arrays are ``pipeline.method.bank_index.content_digest``'s
and the crop seeds' ``pipeline.infra.seeds``'. tests/test_one_of_each.py walks the code."""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
import threading
import zipfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from pipeline.infra.outputs import read_json


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_stream():
    """A running sha256 (``update`` the pieces, then ``hexdigest``) for a digest built piece by
    piece: a code object's parts, a data set's file records."""
    return hashlib.sha256()


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while True:
                b = f.read(chunk)
                if not b:
                    break
                h.update(b)
    except OSError as e:  # a failed read() (EIO) names no file
        raise naming(e, path) from None
    return h.hexdigest()


def hash_json(obj: Any) -> str:
    return sha256_bytes(json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_json_default).encode())


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON-serialisable: {type(o)}")


# ------------------------------------------------------------------------------------------------
# File records: what a manifest keeps of each input it read and each output it wrote.

def file_record(path: str | Path, data: bytes | None = None, known: dict | None = None) -> dict:
    """{sha256, size, mtime_ns} of a file. ``data``: its bytes when already in memory; ``known``:
    a previous record, whose hash is reused when size and mtime are unchanged (no re-read)."""
    st = os.stat(path)
    if known and known.get("size") == st.st_size and known.get("mtime_ns") == st.st_mtime_ns:
        return dict(known)
    digest = sha256_bytes(data) if data is not None else sha256_file(path)
    return {"sha256": digest, "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def record_changed(path: str | Path, rec: dict, verify: dict | None = None, memo: dict | None = None) -> str | None:
    """Why ``path`` no longer matches ``rec`` ("missing", "content changed"), or None.

    Without ``verify``, the same size and mtime are trusted: a fast path that a byte edit with the
    mtime restored fools (the runner and ``viewfuse status`` do not take it). With ``verify`` (a dict
    kept for one run), the bytes are always hashed, once per run per file state, and compared with
    the recorded sha256: what a stage about to use an upstream output does, and what status does. With ``memo`` (``memo_record``; dataset
    files), the sha256 is reused while size, mtime, ctime and inode match: a copied dataset (new
    mtimes) is hashed once, not on every check, and an edit with its mtime restored moves the ctime."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "missing"
    if st.st_size != rec.get("size"):
        return f"content changed (size {rec.get('size')} -> {st.st_size} bytes)"
    if memo is not None:
        digest = memo_record(path, memo)["sha256"]
    elif verify is None:
        if st.st_mtime_ns == rec.get("mtime_ns"):
            return None
        digest = sha256_file(path)
    else:
        k = (os.path.abspath(path), st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
        digest = verify.get(k)
        if digest is None:
            digest = verify[k] = sha256_file(path)
    return None if digest == rec.get("sha256") else "content changed (sha256 differs)"


def folder_records(folder: str | Path, skip: tuple[str, ...] = (), previous: dict | None = None) -> dict:
    """{relative path: file_record} of every file under ``folder`` except the names in ``skip``."""
    folder = Path(folder)
    previous = previous or {}
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_file() and rel not in skip:
            out[rel] = file_record(p, known=previous.get(rel))
    return out


class InputRecorder:
    """Files a stage read (dataset images, masks, HDF5, annotations): the readers call
    ``note_read``; the runner records them in the manifest and checks them on the next run."""

    def __init__(self) -> None:
        self._data: dict[str, bytes | None] = {}
        self._lock = threading.Lock()

    def add(self, path: str | Path, data: bytes | None = None) -> None:
        key = os.path.abspath(path)
        with self._lock:
            if key not in self._data or data is not None:
                # Hash now when the bytes are at hand (they are about to be dropped).
                self._data[key] = sha256_bytes(data) if data is not None else None  # type: ignore[assignment]

    def records(self, exclude: str | Path | None = None) -> dict[str, dict]:
        """{absolute path: file_record} of the files read, except those under ``exclude``."""
        skip = os.path.abspath(exclude) + os.sep if exclude is not None else None
        out = {}
        for key, digest in sorted(self._data.items()):
            if (skip and key.startswith(skip)) or not os.path.isfile(key):
                continue
            st = os.stat(key)
            out[key] = ({"sha256": digest, "size": st.st_size, "mtime_ns": st.st_mtime_ns}
                        if digest is not None else file_record(key))
        return out


_recorders: list[InputRecorder] = []


def note_read(path: str | Path, data: bytes | None = None) -> None:
    """Tell the running stage (if any) that it read ``path`` (``data``: the bytes, if in memory)."""
    for r in _recorders:
        r.add(path, data)


@contextlib.contextmanager
def recording_inputs() -> Iterator[InputRecorder]:
    rec = InputRecorder()
    _recorders.append(rec)
    try:
        yield rec
    finally:
        _recorders.remove(rec)


# ------------------------------------------------------------------------------------------------
# .npz files

class NpzFileError(ValueError):
    """An .npz file is missing or not a readable, pickle-free .npz; the message names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


def load_npz(path: str | Path) -> dict[str, np.ndarray]:
    """All arrays of an .npz file, never unpickling; NpzFileError naming the file otherwise
    (missing, truncated, random bytes, object arrays)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except FileNotFoundError:
        raise NpzFileError(path, "file not found") from None
    except OSError as e:
        raise NpzFileError(path, f"cannot read file ({e.strerror or e})") from None
    if head[:2] != b"PK":
        raise NpzFileError(path, "not a valid .npz file (no zip header; corrupt or not written by numpy)")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except ValueError as e:
        if "pickle" in str(e):
            raise NpzFileError(path, "holds object arrays, which would need unpickling; not loaded") from None
        raise NpzFileError(path, f"not a valid .npz file ({e})") from None
    except (zipfile.BadZipFile, OSError, EOFError, KeyError) as e:
        raise NpzFileError(path, f"not a valid .npz file (truncated or corrupt: {e})") from None


def tree_digest(root: str | Path, memo: dict | None = None, by_name=None, into: dict | None = None) -> str:
    """Content fingerprint of a file tree: sha256 over each file's name relative to ``root`` and
    its sha256, so a moved or copied tree (new paths, new mtimes) keeps it and one changed byte
    moves it. ``memo`` ({absolute path: record}, updated in place) skips rehashing a file whose size,
    mtime, ctime and inode are unchanged: an edit with the mtime restored still moves the ctime.
    ``by_name(rel)`` true: that file enters by name and size only (large files the stage never
    reads; the stages that read them record their sha256). ``into``: where the records used go
    (default ``memo``), so a caller can keep only the current files' records."""
    root = Path(root)
    memo = {} if memo is None else memo
    into = memo if into is None else into
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if not p.is_file():
            continue
        rel = p.relative_to(root).as_posix()
        if by_name is not None and by_name(rel):
            h.update(f"{rel}\0size {p.stat().st_size}\n".encode())
            continue
        h.update(f"{rel}\0{memo_record(p, memo, into)['sha256']}\n".encode())
    return h.hexdigest()


def memo_record(path: str | Path, memo: dict, into: dict | None = None) -> dict:
    """``file_record`` of ``path``, reusing ``memo[absolute path]`` when size, mtime, ctime and
    inode all match (no re-read), else hashing; the record goes into ``into`` (default ``memo``).
    The stat follows a symlink, so a link pointed elsewhere shows a new inode."""
    key = os.path.abspath(path)
    st = os.stat(key)
    known = memo.get(key)
    if not (isinstance(known, dict) and known.get("ctime_ns") == st.st_ctime_ns and known.get("ino") == st.st_ino
            and isinstance(known.get("sha256"), str)):
        known = None
    rec = {**file_record(key, known=known), "ctime_ns": st.st_ctime_ns, "ino": st.st_ino}
    (memo if into is None else into)[key] = rec
    return rec


def remember(records: dict[str, dict], memo: dict) -> None:
    """Put the records of files just read (``InputRecorder.records``) into ``memo`` with their
    ctime and inode, so the next check of them reads nothing."""
    for path, rec in records.items():
        with contextlib.suppress(OSError):
            st = os.stat(path)
            if st.st_size == rec.get("size") and st.st_mtime_ns == rec.get("mtime_ns"):
                memo[os.path.abspath(path)] = {**rec, "ctime_ns": st.st_ctime_ns, "ino": st.st_ino}


def load_memo(path: str | Path) -> dict:
    """A digest memo written by ``save_memo``; {} when missing or unreadable (it is only a memo)."""

    try:
        data = read_json(path, missing={}, invalid={})
    except OSError:
        return {}
    return data if isinstance(data, dict) else {}


def save_memo(path: str | Path, memo: dict) -> None:
    """Write a digest memo into an existing, real (not symlinked) folder; otherwise keep it in memory only."""
    folder = Path(path).parent
    if folder.is_dir() and not folder.is_symlink():
        write_json(path, memo)


# ------------------------------------------------------------------------------------------------
# Confinement: while a stage runs, every file it writes must land inside its temporary folder.

class OutsideFolderError(PermissionError):
    """A write aimed outside the running stage's temporary folder (a name from a dataset file
    with '..' or an absolute path, a symlinked folder leading elsewhere); nothing was written."""


_write_roots: list[str] = []


@contextlib.contextmanager
def confined_writes(root: str | Path) -> Iterator[None]:
    """Within the block, ``confined`` (and so every writer here) refuses targets outside ``root``."""
    _write_roots.append(os.path.realpath(root))
    try:
        yield
    finally:
        _write_roots.pop()


def write_root() -> str | None:
    """The innermost ``confined_writes`` root of this process, or None: what a worker pool hands
    to its processes (``pipeline.infra.workers``), which start with no root of their own."""
    return _write_roots[-1] if _write_roots else None


def confine_process(root: str | None) -> None:
    """In a worker process: confine every write of its life to ``root`` (None: leave it free)."""
    if root is not None:
        _write_roots.append(os.path.realpath(root))


def within(real: str, real_root: str) -> bool:
    """Whether resolved path ``real`` is ``real_root`` or lies below it (both already resolved,
    symlinks followed: ``os.path.realpath``): the one containment test of the project (a stage's
    writes, a dataset file under its root, a bank index's entries)."""
    return os.path.commonpath([real, real_root]) == real_root


def confined(path: str | Path) -> Path:
    """``path`` if it resolves (symlinked folders followed) inside the innermost ``confined_writes``
    root, or when none is active; OutsideFolderError naming both otherwise."""
    path = Path(path)
    if not _write_roots:
        return path
    root = _write_roots[-1]
    # The target itself may not exist yet (or be a link we replace): resolve its folder.
    real = os.path.join(os.path.realpath(path.parent), path.name)
    if path.name in ("", ".", "..") or not within(real, root) or real == root:
        raise OutsideFolderError(f"{path}: resolves to {real}, outside the stage's temporary folder {root}; "
                                 f"refused (nothing written)")
    return path


def confined_dir(path: str | Path) -> Path:
    """Create folder ``path`` (and parents) after checking it stays inside the confinement root."""
    path = Path(path)
    if _write_roots:
        root = _write_roots[-1]
        real = os.path.realpath(path)
        if not within(real, root):
            raise OutsideFolderError(f"{path}: resolves to {real}, outside the stage's temporary folder {root}; "
                                     f"refused (nothing written)")
    path.mkdir(parents=True, exist_ok=True)
    confined(path / "x")  # a symlink created in between would show here
    return path


def link_file(src: str | Path, dst: str | Path) -> None:
    """Hard-link ``src`` at ``dst`` (a confined target; its folder is created)."""
    dst = Path(dst)
    confined_dir(dst.parent)
    os.link(src, confined(dst))


def copy_file(src: str | Path, dst: str | Path) -> None:
    """Copy ``src`` to ``dst`` atomically (a confined target)."""
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` only on success. The target
    must be ``confined`` (inside the running stage's folder)."""
    path = Path(path)
    confined_dir(path.parent)
    confined(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; give artifacts the usual mode
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        named = naming(e, path) if isinstance(e, OSError) else e
        if named is not e:
            raise named from e
        raise


def naming(e: OSError, path: str | Path) -> OSError:
    """``e`` with ``path`` as its file: a failed write() or flush (ENOSPC, EIO; also from pyarrow's
    and numpy's writers) carries an errno but no file name, and "no space left" alone does not say
    which disk. Errors without an errno keep their own words (and type)."""
    if e.filename or e.errno is None:
        return e
    return OSError(e.errno, e.strerror or str(e), str(path))  # the errno's own subclass


def _strict(o: Any) -> Any:
    """Non-finite floats -> None: JSON has no inf/NaN, and browsers and jq reject the tokens."""
    if isinstance(o, dict):
        return {k: _strict(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_strict(v) for v in o]
    if isinstance(o, np.ndarray):
        return _strict(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def write_json(path: str | Path, obj: Any) -> None:
    """Atomic, strict JSON (inf/NaN written as null; summaries keep log10 values where that matters)."""
    text = json.dumps(_strict(obj), indent=2, sort_keys=True, default=_json_default, allow_nan=False)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")


def write_text(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
