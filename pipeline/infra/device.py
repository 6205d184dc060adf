"""Device and thread choice, shared by every torch-using stage."""
from __future__ import annotations

import math
import os
import statistics

# CPUs granted to the task running in this process (set by the Ray executor around each task;
# 0 = not inside a task: use every core).
_TASK_CPUS = 0


def task_cpus() -> int:
    """CPUs the current task may use (0 = all cores): thread pools inside a task should size to it,
    or a cluster node running one task per CPU oversubscribes."""
    return _TASK_CPUS


def resolve_device(requested: str = "auto") -> str:
    """'auto' -> 'cuda' when a GPU is visible, else 'cpu'. 'cuda' without a GPU is an error."""
    import torch

    if requested == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if requested == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("device 'cuda' requested (config run.device or --device) but no CUDA GPU is visible")
    if requested not in ("cpu", "cuda"):
        raise ValueError(f"unknown device {requested!r}; use auto, cpu or cuda")
    return requested


def configure_threads(threads: int = 0) -> int:
    """Use every core by default (2 here); intra-op threads beyond the cores only thrash."""
    import torch

    n = max(1, int(threads or available_cores()))
    torch.set_num_threads(n)
    return n


def available_cores() -> int:
    """Cores this process may use: inside an executor task (a Ray worker), the CPUs granted to the
    task, so that thread pools in it (the fusion engine's) do not oversubscribe a node running one
    task per CPU; otherwise the CPUs this process may run on."""
    if task_cpus():
        return task_cpus()
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def runnable_others(samples: int = 5, gap_s: float = 0.05) -> float:
    """Other processes' runnable threads now: the median over ``samples`` reads of the kernel's
    count of runnable entities (/proc/loadavg, this reader included, so minus one). Unlike the load
    average it does not remember this chain's own previous stage. The 1-minute load average
    (minus one) where /proc is not there."""
    import time

    counts = []
    for i in range(samples):
        try:
            with open("/proc/loadavg") as fh:
                counts.append(int(fh.read().split()[3].split("/")[0]))
        except (OSError, IndexError, ValueError):
            return max(0.0, os.getloadavg()[0] - 1) if hasattr(os, "getloadavg") else 0.0
        if i + 1 < samples:
            time.sleep(gap_s)
    return max(0.0, float(statistics.median(counts)) - 1)


def free_of(cores: int, others: float) -> int:
    """The cores the other runnable threads leave free, at least one: the torch threads for scoring
    in one process, the worker processes for drawing figures. On a shared machine threads beyond the
    free cores wait on each other (EfficientNet-Lite0 on a loaded 2-core machine: 175 ms a crop with
    2 threads, 81 ms with 1). Neither scores nor figures depend on the count
    (tests/pipeline/scoring/test_thread_counts.py, tests/reports/test_figure_pool.py)."""
    return int(min(cores, max(1, math.floor(cores - others + 0.5))))


def free_cores() -> int:
    """``free_of`` this process's cores (``available_cores``) and the other runnable threads now."""
    return free_of(available_cores(), runnable_others())
