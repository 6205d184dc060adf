"""What every executor shares: the retryable error, per-call timing records, item labels.

Kept apart from ``executor`` so that the Ray executor can use them without importing the
factory that imports it.
"""
from __future__ import annotations

from typing import Any


class TransientError(RuntimeError):
    """Raise from a task for a failure worth retrying (a flaky network file system, say); Ray
    retries it, like ``ConnectionError`` and ``TimeoutError``. Other exceptions stop the stage."""


# One record per finished map/imap call, for benchmarks and manifests: executor, desc, tasks,
# slots (tasks that could run at once), wall_s (the call), task_s (sum of the tasks' own times
# measured inside them), task_max_s.
STATS: list[dict] = []


def record(executor: str, desc: str, slots: int, wall_s: float, task_times: list[float]) -> dict:
    rec = {"executor": executor, "desc": desc, "tasks": len(task_times), "slots": int(slots),
           "wall_s": round(wall_s, 4), "task_s": round(float(sum(task_times)), 4),
           "task_max_s": round(max(task_times, default=0.0), 4)}
    STATS.append(rec)
    del STATS[:-1000]  # bounded: a long-lived process keeps the latest
    return rec


def item_label(item: Any, limit: int = 80) -> str:
    """How an item is named in errors: its ``label`` attribute, else a shortened ``repr``."""
    text = getattr(item, "label", None)
    text = str(text) if text is not None else repr(item)
    return text if len(text) <= limit else text[: limit - 3] + "..."
