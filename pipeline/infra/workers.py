"""Worker process pools that never outlive the run that started them.

A pool worker asks the kernel to kill it when its parent dies (Linux ``PR_SET_PDEATHSIG``; a
parent-pid watchdog thread elsewhere), so a run killed with SIGKILL leaves no process writing into
its folder, and the multiprocessing resource tracker, which lives as long as someone holds its
pipe, ends with them. A pool left by an exception (SIGINT, SIGTERM: ``Terminated``) is terminated,
not drained. Each worker appends its pid to the stage's pid file (``<run>/.<stage>.workers``, set
by the runner with ``pid_file``), so a rerun can stop any leftover (``stop_leftovers``). A worker
writes under the same confinement root as the stage that started the pool (``cache.confined``).
"""
from __future__ import annotations

import contextlib
import ctypes
import gc
import ctypes.util
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Callable, Iterator

import psutil

from pipeline.infra.cache import confine_process, write_root

log = logging.getLogger("viewfuse")

PR_SET_PDEATHSIG = 1  # linux/prctl.h
_PID_FILE: list[Path | None] = [None]


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread: the same clean-up path as Ctrl-C (exit 143)."""


def raise_on_sigterm() -> None:
    """Turn SIGTERM into ``Terminated`` in this (main) process."""
    def handler(signum, frame):
        raise Terminated(f"signal {signum}")
    signal.signal(signal.SIGTERM, handler)


@contextlib.contextmanager
def pid_file(path: Path) -> Iterator[Path]:
    """Within the block, pools record their workers' pids in ``path``; removed at the end."""
    _PID_FILE[0] = path
    try:
        yield path
    finally:
        _PID_FILE[0] = None
        path.unlink(missing_ok=True)


def _die_with_parent(parent: int) -> None:
    ok = False
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
            ok = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
    if not ok:
        def watch():
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)
        threading.Thread(target=watch, daemon=True).start()


def _start(parent: int, pids: str, root: str | None, initializer: Callable | None, initargs: tuple) -> None:
    _die_with_parent(parent)
    # A spawned process starts unconfined: it writes under the same root as the stage that started it.
    confine_process(root)
    if pids:
        with contextlib.suppress(OSError):
            fd = os.open(pids, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
            try:
                os.write(fd, record_line(os.getpid()).encode())
            finally:
                os.close(fd)
    if initializer is not None:
        initializer(*initargs)


def can_fork() -> bool:
    """Whether this platform can fork workers (``worker_pool(start_method="fork")``)."""
    return "fork" in multiprocessing.get_all_start_methods()


@contextlib.contextmanager
def worker_pool(workers: int, initializer: Callable | None = None, initargs: tuple = (),
                start_method: str = "spawn") -> Iterator[ProcessPoolExecutor]:
    """A spawn-context ``ProcessPoolExecutor`` whose workers die with this process; on an
    exception (including SIGINT/SIGTERM) the workers are terminated at once. ``start_method``
    "fork": workers inherit this process's memory (for work that needs no new imports or loads)."""
    pids = str(_PID_FILE[0] or "")
    pool = _Pool(workers, mp_context=multiprocessing.get_context(start_method), initializer=_start,
                 initargs=(os.getpid(), pids, write_root(), initializer, initargs))
    try:
        yield pool
    except BaseException as e:
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            with contextlib.suppress(Exception):
                p.kill()
        for p in procs:
            with contextlib.suppress(Exception):
                p.join(5)
        if isinstance(e, BrokenProcessPool):
            for p in getattr(pool, "spawned", ()):   # reap the dead one the broken pool dropped: its exit code
                if p not in procs:
                    with contextlib.suppress(Exception):
                        p.join(5)
            _await_exit_codes(pool.spawned)
            why = worker_deaths(pool.spawned)
            if why:
                raise BrokenProcessPool(why) from e
        raise
    pool.shutdown(wait=True)


class _Pool(ProcessPoolExecutor):
    """A ProcessPoolExecutor that remembers every worker it started: a broken pool drops its
    process table, and with it the exit codes that say how a worker died."""

    def __init__(self, *args, **kwargs):
        self.spawned: list = []
        super().__init__(*args, **kwargs)

    def _spawn_process(self):
        super()._spawn_process()
        self.spawned.extend(p for p in self._processes.values() if p not in self.spawned)


def _await_exit_codes(procs, seconds: float = 2.0) -> None:
    """Wait briefly until each dead worker's exit code can be read. The executor's own thread reaps
    the workers of a broken pool too; while it holds a reaped child's status, our poll gets ECHILD
    and reads None (a race seen under load), so poll again for a moment."""
    deadline = time.monotonic() + seconds
    for p in procs:
        while getattr(p, "exitcode", 0) is None and time.monotonic() < deadline:
            time.sleep(0.01)


def worker_deaths(procs) -> str:
    """How the workers that ended on their own ended ('' when none did or none can say): a
    signal by name (a kill -9, the kernel's out-of-memory killer), or an exit status."""
    out = []
    for p in procs:
        code = getattr(p, "exitcode", None)
        if code is None or code == 0:
            continue
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            hint = " (kill -9, or the kernel's out-of-memory killer)" if -code == signal.SIGKILL else ""
            out.append(f"worker process {p.pid} was killed by {name}{hint}")
        else:
            out.append(f"worker process {p.pid} exited with status {code}")
    return "; ".join(out)


# What forked workers read: set by ``forked_pool`` just before its pool forks them, so each worker
# inherits these objects (copy-on-write) instead of receiving them pickled.
_INHERITED: dict[str, Any] = {}


def inherited(key: str) -> Any:
    """In a ``forked_pool`` worker (or its parent while the pool lives): the object set under ``key``."""
    return _INHERITED[key]


@contextlib.contextmanager
def forked_pool(workers: int, inherit: dict[str, Any], initializer: Callable | None = None,
                initargs: tuple = ()) -> Iterator[ProcessPoolExecutor]:
    """``worker_pool(..., start_method="fork")`` whose workers inherit ``inherit`` (read with
    ``inherited(key)``). While it lives, the objects built so far are out of the collector's reach:
    a worker's collections would otherwise write to (and so copy) every page it inherited."""
    _INHERITED.update(inherit)
    gc.freeze()
    try:
        with worker_pool(workers, initializer, initargs, start_method="fork") as pool:
            yield pool
    finally:
        gc.unfreeze()
        for key in inherit:
            _INHERITED.pop(key, None)


def _start_mark(pid: int) -> str:
    """When ``pid`` started, in a form that another process reads the same: on Linux the kernel's
    start tick (``/proc/<pid>/stat``, counted from boot, so no wall-clock step or boot-time rounding
    moves it); elsewhere psutil's start time."""
    with contextlib.suppress(OSError, IndexError):
        stat = Path(f"/proc/{pid}/stat").read_text()
        return "t" + stat[stat.rindex(")") + 2:].split()[19]   # field 22: starttime
    return f"c{psutil.Process(pid).create_time():.2f}"


def record_line(pid: int) -> str:
    """A pid file's line for ``pid``: the pid and its start, so a later run knows the process again
    (a pid the kernel has handed to another program since has another start)."""
    return f"{pid} {_start_mark(pid)}\n"


def _ours(p: psutil.Process, started: str) -> bool:
    return p.pid != os.getpid() and _start_mark(p.pid) == started and \
        any("multiprocessing" in a for a in p.cmdline())


def stop_leftovers(path: Path, timeout: float = 10.0) -> list[int]:
    """Kill the workers a dead run recorded in ``path`` that still live (a pid reused since by
    another program is left alone: only a process with the recorded start time that runs Python's
    multiprocessing is ours); wait for them to end; remove the file. Returns their pids."""
    try:
        text = path.read_text()
    except OSError:
        return []
    procs = []
    for line in text.splitlines():
        # "<pid> <start>"; a line without a start (an older file) cannot be told from a reused pid
        with contextlib.suppress(ValueError, psutil.Error):
            pid, started = line.split()
            p = psutil.Process(int(pid))
            if _ours(p, started):
                procs.append(p)
    for p in procs:
        with contextlib.suppress(psutil.Error):
            p.kill()
    psutil.wait_procs(procs, timeout=timeout)
    if procs:
        log.warning("stopped %d worker process(es) a killed run left (pids %s; %s)",
                    len(procs), ", ".join(str(p.pid) for p in procs), path)
    path.unlink(missing_ok=True)
    return [p.pid for p in procs]
