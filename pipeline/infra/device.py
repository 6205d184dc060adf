"""Device and thread choice, shared by every torch-using stage."""
from __future__ import annotations

import os

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
