"""The run folder's safety: where the runner may write, one run per stage at a time, the folder
swap and its recovery, and the clean-up of what killed runs left.

Everything the runner creates, swaps or deletes is directly inside ``<artifacts>/<run>/``
(``stage_paths``; ``run.name`` is one plain folder name), and it deletes only folders with a
stage's name that carry its owner marker (``.owner``, the writing pid) or are empty: a folder
someone else put there is never removed. A stage runs under an advisory lock on
``<run>/.<stage>.lock`` (``fcntl.flock``): a second process running the same stage waits for the
first, then finds its output up to date.
"""
from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from pipeline.infra.config import Config, ConfigError
from pipeline.infra.config.checks import RUN_NAME
from pipeline.infra.outputs import MANIFEST
from pipeline.infra.progress import echo
from stages.framework import registry

log = logging.getLogger("viewfuse")

OWNER = ".owner"  # pid of the process writing a temporary stage folder


@dataclass(frozen=True)
class StagePaths:
    run_dir: Path
    final: Path   # <artifacts>/<run>/<stage>
    tmp: Path     # .<stage>.tmp: the running stage's output
    old: Path     # .<stage>.old: the previous output during the swap
    lock: Path    # .<stage>.lock: held (flock) while a process runs the stage


def stage_paths(cfg: Config, stage: str) -> StagePaths:
    """The paths the runner may create, swap or delete for ``stage``: all directly inside
    ``<artifacts>/<run>/``. A run name that is not one plain folder name, or a run folder that is a
    symlink (it would lead the writes elsewhere), is refused before anything is touched."""
    name = cfg.run.name
    if not RUN_NAME.fullmatch(name) or not name.strip(".") or not RUN_NAME.fullmatch(stage):
        raise ConfigError(f"'run.name' = {name!r} must be a plain folder name (no '/', '..' or NUL)")
    run_dir = cfg.artifacts_dir / name
    if run_dir.is_symlink():
        raise RuntimeError(f"{run_dir}: the run folder is a symlink; refusing to write through it "
                           f"(set run.artifacts to where the outputs should go)")
    return StagePaths(run_dir, run_dir / stage, run_dir / f".{stage}.tmp", run_dir / f".{stage}.old",
                      run_dir / f".{stage}.lock")


def mark_owned(folder: Path) -> None:
    """Mark a folder as the runner's own (the pid writing it): only marked folders are deleted."""
    (folder / OWNER).write_text(str(os.getpid()))


def remove_leftover(p: Path, required: bool = False) -> bool:
    """Delete a temporary folder a run left: a symlink (the link only), an empty folder, or a
    folder carrying the owner marker. Anything else is not ours: kept, and with ``required`` (it
    is in the way of the stage) an error naming it."""
    if p.is_symlink():
        p.unlink()
        return True
    if p.is_dir():
        if (p / OWNER).is_file():
            shutil.rmtree(p)
            return True
        with contextlib.suppress(OSError):
            p.rmdir()  # only succeeds when empty
            return True
    if required:
        raise RuntimeError(f"{p}: not created by viewfuse (no {OWNER} marker) and in the way of the stage; "
                           f"move it away")
    log.warning("left %s in place: not created by viewfuse (no %s marker)", p, OWNER)
    return False


def swap_in(paths: StagePaths) -> None:
    """Replace the stage folder by the finished temporary one: final -> .old, .tmp -> final, then
    delete .old. A crash between the renames leaves .old and a finished .tmp, which
    ``recover_swap`` completes; the .old folder carries the owner marker so it can be removed."""
    final, tmp, old = paths.final, paths.tmp, paths.old
    if old.exists() or old.is_symlink():
        remove_leftover(old, required=True)
    if final.exists() or final.is_symlink():
        if final.is_dir() and not final.is_symlink():
            mark_owned(final)
        os.replace(final, old)
    os.replace(tmp, final)
    (final / OWNER).unlink(missing_ok=True)
    if old.exists() or old.is_symlink():
        remove_leftover(old)
    # mtimes survive the rename, so the manifest's records still match the final files.


def recover_swap(cfg: Config, stage: str) -> str | None:
    """Finish a folder swap a killed run interrupted (no stage folder, but a finished .tmp: it
    becomes the stage folder; or only the previous .old: it is put back); say what was done.
    The caller holds the stage's lock."""
    paths = stage_paths(cfg, stage)
    final, tmp, old = paths.final, paths.tmp, paths.old
    if final.exists() or final.is_symlink():
        return None
    done = None
    if tmp.is_dir() and not tmp.is_symlink() and (tmp / MANIFEST).is_file() and (tmp / OWNER).is_file():
        os.replace(tmp, final)
        done = f"finished the output swap an interrupted run left ({tmp.name} -> {final})"
    elif old.is_dir() and not old.is_symlink() and (old / OWNER).is_file() and (old / MANIFEST).is_file():
        os.replace(old, final)
        done = f"restored the previous output an interrupted run had moved aside ({old.name} -> {final})"
    if done is None:
        return None
    (final / OWNER).unlink(missing_ok=True)
    for p in (tmp, old):  # what is left is the swap's trash or an unfinished output, both marked
        if p.exists() or p.is_symlink():
            remove_leftover(p)
    echo(f"[{stage}] {done}")
    return done


@contextlib.contextmanager
def stage_lock(cfg: Config, stage: str, wait: bool = True) -> Iterator[bool]:
    """Hold ``<run>/.<stage>.lock`` (an advisory ``fcntl.flock``) for a stage's run: a second
    process running the same stage waits, with a message, until the first is done (``wait=False``:
    yields False instead of waiting). The kernel drops the lock when its holder dies, so a killed
    run never blocks the next one. The holder deletes the file when done (leaving the run folder
    clean); a process that locked a file deleted meanwhile locks the new one instead."""
    paths = stage_paths(cfg, stage)
    paths.run_dir.mkdir(parents=True, exist_ok=True)
    told = False
    while True:
        fd = os.open(paths.lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not wait:
                os.close(fd)
                yield False
                return
            if not told:
                holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
                echo(f"[{stage}] waiting: another viewfuse process (pid {holder}) is running this stage "
                     f"in {paths.run_dir}")
                told = True
            fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            same = os.stat(paths.lock, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the previous holder deleted this file: lock the current one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield True
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(paths.lock)
        os.close(fd)  # releases the lock


def remove_orphans(cfg: Config) -> list[Path]:
    """Remove the ``.<stage>.tmp`` / ``.<stage>.old`` folders of this run that a killed run left
    (first finishing a swap it interrupted: ``recover_swap``); return what was removed. Only
    folders with a stage's name that carry the runner's owner marker (or are empty) are touched,
    and none of a stage another process is running."""
    removed: list[Path] = []
    if not stage_paths(cfg, "data").run_dir.is_dir():
        return removed
    for name in registry.STAGES:
        paths = stage_paths(cfg, name)
        if not any(p.exists() or p.is_symlink() for p in (paths.tmp, paths.old)):
            continue
        with stage_lock(cfg, name, wait=False) as held:
            if not held:
                continue  # that stage is running in another process: its folders are live
            recover_swap(cfg, name)
            for p in (paths.tmp, paths.old):
                if (p.exists() or p.is_symlink()) and not _writer_alive(p / OWNER) and remove_leftover(p):
                    removed.append(p)
                    log.info("removed %s, left by an interrupted run", p)
    return removed


def _writer_alive(owner: Path) -> bool:
    try:
        pid = int(owner.read_text())
    except (OSError, ValueError):
        return False
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
