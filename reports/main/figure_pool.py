"""Draw the report's figures: one after another in this process, or independent figures at once in
a pool of worker processes (matplotlib is not thread-safe; each worker draws on its own Agg canvas).

The workers are forked once the plan is built, so they start with the run already loaded and the
track summaries made (a spawned worker spent seconds importing and loading again, on a machine
with two cores); they draw the figures they are handed by name, and the PNG bytes and the checks
are the same as the serial route's (tests/reports/test_figure_pool.py). Results come back in the
plan's order whatever the order the workers finish in. Where processes cannot fork, the figures are
drawn in this process.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import psutil

from pipeline.infra.budget import AUTO_SHARE, cap_workers, machine_memory
from pipeline.infra.device import free_cores
from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.workers import can_fork, forked_pool, inherited
from reports.shared.figures import FigureCheck, save

Plan = list[tuple[str, Callable[[], Any]]]
# (name, its check, what the figure's builder recorded in the plan's ``clipped`` for it)
Drawn = tuple[str, FigureCheck, Any]


def pool_size(n_figures: int, requested: int | None = None) -> int:
    """Worker processes for ``n_figures`` figures: ``requested``, or the free cores (``None``:
    ``pipeline.infra.device.free_cores``, as the features stage's scoring threads), at
    most one per figure and as many as the memory beside this process holds (a worker's pages
    are this process's until it writes to them: at most about this process's size). 1 where
    processes cannot fork."""
    if not can_fork():
        return 1
    want = free_cores() if requested is None else max(1, int(requested))
    want = min(want, max(n_figures, 1))
    if want <= 1:
        return 1
    rss = float(psutil.Process().memory_info().rss)
    return cap_workers("report.workers", want, rss, int(AUTO_SHARE * machine_memory()), parent=rss)


def draw_one(name: str, build: Callable[[], Any], out: Path, dpi: int, clipped: dict) -> Drawn:
    """Build one figure, finish and write it (``reports.shared.figures.save``)."""
    chk = save(build(), Path(out) / name, dpi)
    return name, chk, clipped.get(name)


def _draw_named(name: str, out: str, dpi: int) -> Drawn:
    return draw_one(name, inherited("figure_plan")[name], Path(out), dpi, inherited("figure_clipped"))


def draw_parallel(plan: Plan, out: Path, dpi: int, workers: int, clipped: dict, progress: bool) -> list[Drawn]:
    """Draw ``plan``'s figures in ``workers`` forked processes; the builders record into ``clipped``
    in the workers, so what they recorded comes back with each figure."""
    # each worker inherits the built plan (the run loaded, the summaries made) instead of rebuilding it
    with forked_pool(workers, {"figure_plan": dict(plan), "figure_clipped": clipped}) as pool:
        futures = [pool.submit(_draw_named, name, str(out), dpi) for name, _ in plan]
        return [f.result() for f in progress_bar(futures, desc="report figures", unit="fig", enabled=progress)]
