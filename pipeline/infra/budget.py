"""The run's memory budget (``run.memory_gb``) and the checks every stage makes against it.

A stage whose peak memory grows with a setting either bounds the work per step (a batch size or
a worker count capped here, logged) or, where the work cannot stream (the classifier's in-memory
training set), estimates its peak before it starts and refuses with the key, the estimate and the
budget. The estimates are upper-bound rules of thumb from the arrays each step holds (their
derivations sit beside the callers); they need to be right within a small factor, not exactly.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import psutil

from pipeline.infra.config.fields import ConfigError

log = logging.getLogger("viewfuse")

GIB = 1 << 30
AUTO_SHARE = 0.8  # run.memory_gb = 0: this share of the machine's (or the cgroup's) memory
_CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")


class MemoryBudgetError(ConfigError):
    """A setting would need more memory than ``run.memory_gb`` allows (a config error: exit 2)."""


def machine_memory() -> int:
    """Bytes of memory this process may use: physical memory, or a lower cgroup limit."""
    total = int(psutil.virtual_memory().total)
    for p in _CGROUP_LIMITS:
        try:
            v = Path(p).read_text().strip()
        except OSError:
            continue
        if v.isdigit():
            total = min(total, int(v))
    return total


def budget(cfg) -> int:
    """The run's memory budget in bytes (``run.memory_gb``; 0 = ``AUTO_SHARE`` of ``machine_memory``)."""
    gb = float(cfg.run.memory_gb)
    return int(gb * GIB) if gb > 0 else int(AUTO_SHARE * machine_memory())


def gib(n: float) -> str:
    return f"{n / GIB:.2f} GiB" if n < 100 * GIB else f"{n / GIB:.0f} GiB"


def require(key: str, value, estimate: float, limit: int, what: str) -> None:
    """Refuse (``MemoryBudgetError`` naming ``key``) when ``estimate`` bytes exceed ``limit``."""
    if estimate > limit:
        raise MemoryBudgetError(
            f"'{key}' = {value}: {what} needs about {gib(estimate)}, over the memory budget of {gib(limit)} "
            f"(run.memory_gb; 0 = {AUTO_SHARE:.0%} of this machine's {gib(machine_memory())}); "
            f"lower '{key}' or raise run.memory_gb")


def cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def cap_workers(key: str, requested: int, per_worker: float, limit: int, parent: float = 0.0) -> int:
    """``requested`` worker processes, capped by the cores and by the memory left beside the
    parent (``parent`` bytes) at ``per_worker`` bytes each; the cap is logged."""
    by_memory = int(max(limit - parent, 0) // max(per_worker, 1.0))
    n = max(1, min(int(requested), cores(), by_memory))
    if n < requested:
        why = "cores" if n == cores() and n < by_memory else f"memory (about {gib(per_worker)} each, budget {gib(limit)})"
        log.warning("%s = %d capped to %d worker processes by this machine's %s", key, requested, n, why)
    return n


def cap_batch(key: str, requested: int, per_item: float, limit: float) -> int:
    """A batch of ``requested`` items capped so that it holds at most ``limit`` bytes at
    ``per_item`` bytes each (at least 1); the cap is logged."""
    n = max(1, min(int(requested), int(limit // max(per_item, 1.0))))
    if n < requested:
        log.warning("%s = %d capped to %d per batch by the memory budget (about %s each, %s for a batch)",
                    key, requested, n, gib(per_item), gib(limit))
    return n
