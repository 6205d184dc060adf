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
import resource
from pathlib import Path

import psutil

from pipeline.infra.config.fields import ConfigError

log = logging.getLogger("viewfuse")

GIB = 1 << 30
AUTO_SHARE = 0.8  # run.memory_gb = 0: this share of the machine's (or the cgroup's) memory
_CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")


class MemoryBudgetError(ConfigError):
    """A setting would need more memory than ``run.memory_gb`` allows (a config error: exit 2)."""


def address_space_left() -> int | None:
    """Bytes of address space this process may still map under its ``RLIMIT_AS`` (``ulimit -v``),
    or None without such a limit. The limit counts mappings, not resident pages, and a process
    with its imports already maps much more than it holds (torch: about a GiB), so what is left
    beside what it maps now is the bound on what it can still allocate."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    return max(int(soft) - int(psutil.Process().memory_info().vms), 0)


def memory_limits() -> dict[str, int]:
    """What bounds this process's memory, in bytes: physical memory, the cgroup limit where one is
    set, and the address space ``RLIMIT_AS`` leaves (``address_space_left``) where one is set."""
    out = {"physical memory": int(psutil.virtual_memory().total)}
    for p in _CGROUP_LIMITS:
        try:
            v = Path(p).read_text().strip()
        except OSError:
            continue
        if v.isdigit():
            out["the cgroup limit"] = min(int(v), out.get("the cgroup limit", int(v)))
    left = address_space_left()
    if left is not None:
        # What the process may hold at its peak, in the terms the estimates use (resident bytes,
        # the process's own included): what it holds now plus what it may still map. Counting the
        # limit less everything mapped and then the process's own bytes again counted them twice.
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        rss = int(psutil.Process().memory_info().rss)
        out[f"the address-space limit (ulimit -v, RLIMIT_AS) of {gib(soft)}: the {gib(rss)} this process holds "
            f"and the {gib(left)} it may still map"] = rss + left
    return out


def machine_memory() -> int:
    """Bytes of memory this process may use: the lowest of ``memory_limits``."""
    return min(memory_limits().values())


def budget(cfg) -> int:
    """The run's memory budget in bytes: ``run.memory_gb``, or with 0 ``AUTO_SHARE`` of
    ``machine_memory``. A setting above what this process may use is lowered to it, with a
    warning: the estimates are checked against memory the process can have, not memory it was
    promised (an address-space limit fails allocations long before physical memory runs out)."""
    gb = float(cfg.run.memory_gb)
    if gb <= 0:
        return int(AUTO_SHARE * machine_memory())
    limits = memory_limits()
    what, have = min(limits.items(), key=lambda kv: kv[1])
    if gb * GIB > have:
        _warn_once(f"run.memory_gb = {gb:g} is more than this process may use: {gib(have)} ({what}); "
                   f"the memory budget is {gib(have)}")
        return have
    return int(gb * GIB)


_WARNED: set[str] = set()


def _warn_once(msg: str) -> None:
    if msg not in _WARNED:
        _WARNED.add(msg)
        log.warning("%s", msg)


def gib(n: float) -> str:
    return f"{n / GIB:.2f} GiB" if n < 100 * GIB else f"{n / GIB:.0f} GiB"


def budget_words() -> str:
    """Where the budget comes from, for a refusal: the setting and what bounds this process."""
    what, have = min(memory_limits().items(), key=lambda kv: kv[1])
    return f"run.memory_gb; 0 = {AUTO_SHARE:.0%} of the {gib(have)} this process may use: {what}"


def more_memory(need: float) -> str:
    """Advice that works for ``need`` bytes: raise run.memory_gb where what bounds this process
    allows that much (a setting above it is lowered to it: ``budget``), else lift that bound."""
    what, have = min(memory_limits().items(), key=lambda kv: kv[1])
    if need <= have:
        return f"raise run.memory_gb to at least {need / GIB:.2f}"
    if what.startswith("the address-space limit"):
        return f"raise the address-space limit (ulimit -v) by at least {gib(need - have)}"
    if what == "the cgroup limit":
        return f"raise the cgroup's memory limit by at least {gib(need - have)}"
    return f"run on a machine with at least {gib(need)} of memory"


def require(key: str, value, estimate: float, limit: int, what: str) -> None:
    """Refuse (``MemoryBudgetError`` naming ``key``) when ``estimate`` bytes exceed ``limit``."""
    if estimate > limit:
        raise MemoryBudgetError(
            f"'{key}' = {value}: {what} needs about {gib(estimate)}, over the memory budget of {gib(limit)} "
            f"({budget_words()}); lower '{key}' or {more_memory(estimate)}")


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
