"""Torch threads that follow the machine: passive waiting, and a thread count re-chosen every
``INTERVAL_S`` from the cores other processes leave free now.

On a shared machine two OpenMP threads at a barrier, one of them descheduled, used to spin: the
features stage of real_full used 1,108 CPU s under a load of 12-15 against 364 CPU s idle. Two
measures, both needed:

* **No spinning** (``passive_waiting``): libgomp, torch's OpenMP runtime in the Linux wheels,
  spins ``GOMP_SPINCOUNT`` iterations before it sleeps on a futex. Measured on the 2-core AMD
  EPYC beside two nice-0 busy loops (a small conv net, 60 forward passes, two threads): 3.1-4.0
  CPU s with the default, 1.4-1.6 with ``OMP_WAIT_POLICY=PASSIVE``, 0.7-0.8 with
  ``GOMP_SPINCOUNT=0``; ``KMP_BLOCKTIME=0`` (Intel's runtime) changed nothing there. The
  variables are read once, when the runtime loads, so they are set as the ``pipeline`` package
  is imported (before torch), and only where the user has not set them.
* **A thread count per interval** (``CoreWatch``): the CPU time other processes got over the
  last interval (``/proc/stat``'s busy jiffies less this process's own CPU time) is what they
  keep taking; the rest is free. Time at a positive nice level (the ``nice`` column) counts as
  free for a process at nice 0, which the kernel serves about 70 times first (weights 1024 against
  15 at nice 19). At least one thread, at most the cores this process may use.
"""
from __future__ import annotations

import contextlib
import math
import os
import time
from typing import Callable, Iterator

INTERVAL_S = 1.0   # re-choose the count at most this often: a /proc read is ~20 us, a team resize ~ms
PASSIVE_ENV = {"GOMP_SPINCOUNT": "0", "KMP_BLOCKTIME": "0"}


def passive_waiting() -> None:
    """Make the OpenMP runtime sleep, not spin, at its barriers (where the user has not chosen)."""
    for k, v in PASSIVE_ENV.items():
        os.environ.setdefault(k, v)


def _jiffies() -> tuple[float, float, float] | None:
    """(busy, nice, total) jiffies of the whole machine since boot, or None without /proc/stat."""
    try:
        with open("/proc/stat") as fh:
            f = [float(x) for x in fh.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    user, nice, system, idle, iowait, irq, softirq, steal = (f + [0.0] * 8)[:8]
    return user + system + irq + softirq + steal, nice, user + nice + system + idle + iowait + irq + softirq + steal


def free_from(cores: int, machine_cores: int, others_busy: float) -> int:
    """Threads for ``cores`` usable cores when other processes kept ``others_busy`` of the
    machine's ``machine_cores`` cores busy: the rest, rounded, at least one."""
    free = min(float(cores), machine_cores - max(others_busy, 0.0))
    return int(min(cores, max(1, math.floor(free + 0.5))))


class CoreWatch:
    """The free cores now, re-measured at most every ``interval_s``: ``threads()``."""

    def __init__(self, cores: int, interval_s: float = INTERVAL_S):
        self.cores = max(1, int(cores))
        self.interval_s = interval_s
        self.machine = os.cpu_count() or self.cores
        self._tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
        self._niced_is_free = _own_nice() <= 0
        self._last = self._sample()
        self.n = self.cores
        self._set: int | None = None  # the count pace() last set
        self.counts: dict[int, int] = {}   # how many intervals ran at each count (for the manifest)

    def _sample(self):
        return time.monotonic(), time.process_time(), _jiffies()

    def threads(self) -> int:
        now = time.monotonic()
        if now - self._last[0] >= self.interval_s:
            cur = self._sample()
            (t0, c0, j0), (t1, c1, j1) = self._last, cur
            if j0 is not None and j1 is not None and t1 > t0:
                busy = (j1[0] - j0[0]) + (0.0 if self._niced_is_free else j1[1] - j0[1])
                others = busy / self._tick - (c1 - c0)   # CPU seconds the others got
                self.n = free_from(self.cores, self.machine, others / (t1 - t0))
            self._last = cur
            self.counts[self.n] = self.counts.get(self.n, 0) + 1
        return self.n


def _own_nice() -> int:
    try:
        return os.getpriority(os.PRIO_PROCESS, 0)
    except (AttributeError, OSError):
        return 0


_ACTIVE: list[tuple[CoreWatch, Callable[[int], None]]] = []


@contextlib.contextmanager
def following_cores(cores: int, set_threads: Callable[[int], None],
                    interval_s: float = INTERVAL_S) -> Iterator[CoreWatch]:
    """Within the block, ``pace()`` (called by the work loops once a batch) sets the thread
    count with ``set_threads`` to the cores free now."""
    watch = CoreWatch(cores, interval_s)
    _ACTIVE.append((watch, set_threads))
    try:
        yield watch
    finally:
        _ACTIVE.remove((watch, set_threads))


def pace() -> None:
    """Once per batch of a work loop: where ``following_cores`` is active in this process, set the
    thread count it chooses now (a no-op elsewhere: worker processes, explicit --threads)."""
    if _ACTIVE:
        watch, set_threads = _ACTIVE[-1]
        n = watch.threads()
        if n != watch._set:
            set_threads(n)
            watch._set = n


def torch_following(cores: int, interval_s: float = INTERVAL_S):
    """``following_cores`` that sets torch's intra-op threads."""
    import torch

    return following_cores(cores, torch.set_num_threads, interval_s)
