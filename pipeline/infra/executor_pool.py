"""The local executor with worker processes: ``LocalPool(n)`` runs its tasks in n forked processes
of this machine instead of one after another in this process (``executor.LocalExecutor``); the
same interface and the same outputs (the evaluate stage's cells and planning episodes use it).
Its own module, so the stages that only run ``LocalExecutor`` (features) do not change key with it.

Why forked: the workers start with the stage's inputs already loaded and the ``shared`` payload
(the model banks) already in memory, copy-on-write, so nothing is pickled per task but the item
and its result; a spawned worker would import and load again. The pool lives as long as the
executor and is reused by every call with the same ``shared`` object (the evaluate stage's cells
and then its planning episodes: compiled kernels and cached factors stay warm in the workers);
another ``shared`` object forks a new pool.

Results come back in item order, whatever order the workers finish in, and each task is told its
share of the cores (``pipeline.infra.device.task_cpus``, as a Ray task is), so a task's own
thread pools (the fusion engine's) do not oversubscribe the machine. A task's result does not
depend on the process it ran in: every random draw derives from the item (docs/design.md §11).
Workers die with this process (``pipeline.infra.workers``).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from collections import deque
from typing import Any, Callable, Iterable, Iterator

from pipeline.infra.tasks import record
from pipeline.infra.workers import can_fork, forked_pool, inherited
import pipeline.infra.device as dev
from pipeline.infra.device import available_cores
from pipeline.infra.executor import LocalExecutor
from pipeline.infra.progress import bar as progress_bar

def _run(fn: Callable[[Any, Any], Any], item: Any, cpus: int, which: int | None) -> list[tuple[Any, float]]:
    """In a worker: [(``fn(shared, item)``, its seconds)], with ``task_cpus()`` = ``cpus``; where
    ``which`` is not None, ``item`` is a range of that inherited list and each of its items runs."""

    dev._TASK_CPUS = cpus
    items = [item] if which is None else [inherited("pool_lists")[which][i] for i in item]
    shared = inherited("pool_shared")
    out = []
    for one in items:
        t0 = time.perf_counter()
        out.append((fn(shared, one), time.perf_counter() - t0))
    return out


def _init_worker(cpus: int) -> None:
    """A worker's BLAS gets its share of the cores, as its tasks' own thread pools do: more
    threads than cores spin against the other workers."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - installed with scikit-learn
        return
    threadpool_limits(limits=cpus, user_api="blas")


class ForkPool:
    """``processes`` forked workers, made on the first call and kept for calls with the same
    ``shared`` object."""

    def __init__(self, processes: int, cpus_per_task: int = 1):
        self.processes = int(processes)
        self.cpus = max(1, int(cpus_per_task))
        self._pool = None
        self._context = None
        self._shared: Any = None
        self.lists: tuple[list, ...] = ()

    def _inherited(self, items) -> int | None:
        """Which of the lists the workers inherit ``items`` is (the same object), else None."""
        return next((i for i, lst in enumerate(self.lists) if lst is items), None)

    def _ensure(self, shared: Any):
        if self._pool is not None and self._shared is shared:
            return self._pool
        self.close()
        self._shared = shared
        self._context = forked_pool(self.processes, {"pool_shared": shared, "pool_lists": self.lists},
                                    _init_worker, (self.cpus,))
        self._pool = self._context.__enter__()
        return self._pool

    def imap(self, fn: Callable[[Any, Any], Any], items: Iterable[Any], shared: Any) -> Iterator[tuple[Any, float]]:
        """(result, task seconds) per item, in item order; at most twice the workers in flight, so
        the items are read as the workers keep up."""
        which = self._inherited(items)
        start = 0
        if self._pool is None or self._shared is not shared:
            # Warm start: the first task runs here, before the fork, so that the workers inherit
            # what it compiled and cached (the fusion engine's numba kernels, ~8 CPU s a process,
            # and its basis factors) instead of each making them again.
            if which is None:
                items = iter(items)
                first = next(items, _END)
            else:
                first = items[0] if len(items) else _END
            if first is _END:
                return
            t0 = time.perf_counter()
            out = fn(shared, first)
            yield out, time.perf_counter() - t0
            start = 1
        if which is None:
            source = iter(items)
        else:
            # runs of consecutive items per task: neighbours share work that a worker caches (a
            # target's cells its GPs' basis factors), so fewer workers make the same factors
            n = len(items)
            step = max(1, -(-(n - start) // (8 * self.processes)))
            source = iter([range(i, min(n, i + step)) for i in range(start, n, step)])
        pending: deque = deque()
        pool = self._ensure(shared)
        try:
            for item in source:
                pending.append(pool.submit(_run, fn, item, self.cpus, which))
                if len(pending) >= 2 * self.processes:
                    break
            while pending:
                outs = pending.popleft().result()
                item = next(source, _END)
                if item is not _END:
                    pending.append(pool.submit(_run, fn, item, self.cpus, which))
                yield from outs
        except BaseException:
            for fut in pending:
                fut.cancel()
            self.close(failed=True)
            raise

    def close(self, failed: bool = False) -> None:
        if self._context is not None:
            context, self._context, self._pool = self._context, None, None
            try:
                if failed:   # the workers are terminated, not drained
                    context.__exit__(RuntimeError, RuntimeError("task failed"), None)
                else:
                    context.__exit__(None, None, None)
            except RuntimeError:
                pass
        self._shared = None


_END = object()


class LocalPool:
    """``executor.LocalExecutor``'s interface, its tasks in ``processes`` forked workers (each
    told ``available_cores() // processes`` CPUs); in this process where processes cannot fork."""
    name = "local"
    gpus = 0

    def __init__(self, processes: int):
        self.processes = max(1, int(processes)) if can_fork() else 1
        self._pool = ForkPool(self.processes, max(1, available_cores() // self.processes))

    def imap(self, fn, items, *, shared=None, desc: str = "", unit: str = "task", total=None,
             gpu: bool = False) -> Iterator:
        if self.processes == 1:
            yield from LocalExecutor().imap(fn, items, shared=shared, desc=desc, unit=unit, total=total)
            return
        times: list[float] = []
        t0 = time.perf_counter()
        with progress_bar(total=total, desc=desc, unit=unit, leave=False) as bar:
            for out, took in self._pool.imap(fn, items, shared):
                times.append(took)
                yield out
                bar.update(1)
        record(self.name, desc, self.processes, time.perf_counter() - t0, times)

    def inherit(self, *lists: list) -> None:
        """Before the first call: the workers inherit these lists, and a call whose items are one
        of them (the same object) sends each task only its index. Nothing of the item is pickled:
        a pickled copy of an array view comes back in another memory layout, and numpy's
        reductions may round differently by layout (the cells' dropout statistics did, in the
        last bits), so the tasks compute on exactly what this process holds."""
        self._pool.lists = tuple(lists)

    def map(self, fn, items: Sequence, *, shared=None, desc: str = "", unit: str = "task", gpu: bool = False) -> list:
        return list(self.imap(fn, items, shared=shared, desc=desc, unit=unit, total=len(items)))

    def close(self) -> None:
        self._pool.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
