"""Draw the report's figures: one after another in this process, or independent figures at once in
a pool of worker processes (matplotlib is not thread-safe; each worker draws on its own Agg canvas).

A figure's drawing depends on nothing but the run's artifacts and the report's arguments, so a
worker rebuilds the plan from those (``rebuild``: a module-level function and its keyword
arguments, which pickle) and draws the figures it is handed by name; the PNG bytes and the
checks are the same as the serial route's (tests/reports/test_figure_pool.py). Results come back
in the plan's order whatever the order the workers finish in.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

import psutil

from pipeline.infra.budget import AUTO_SHARE, cap_workers, machine_memory
from pipeline.infra.device import available_cores
from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.workers import worker_pool
from reports.shared.figures import FigureCheck, save

Plan = list[tuple[str, Callable[[], Any]]]
# (name, its check, what the figure's builder recorded in the plan's ``clipped`` for it)
Drawn = tuple[str, FigureCheck, Any]


def free_cores() -> int:
    """Cores not busy with other work: this process's cores less the one-minute load beyond this
    process itself (the machine may be shared; more processes than free cores only queue)."""
    n = available_cores()
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):     # pragma: no cover - not Unix
        return n
    return max(1, min(n, int(n - max(0.0, load - 1.0) + 0.5)))


def pool_size(n_figures: int, requested: int | None = None) -> int:
    """Worker processes for ``n_figures`` figures: ``requested``, or the free cores (``None``), at
    most one per figure and as many as the memory beside this process holds (a worker loads
    the run again, about this process's size)."""
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


# a worker's plan, rebuilt once by its initializer: "plan" (name -> builder) and the plan's own
# ``clipped`` dict, which its builders record into
_WORKER: dict[str, Any] = {}


def _init_worker(rebuild: Callable[..., tuple[Plan, dict]], kwargs: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    plan, clipped = rebuild(**kwargs)
    _WORKER.update(plan=dict(plan), clipped=clipped)


def _draw_named(name: str, out: str, dpi: int) -> Drawn:
    plan = _WORKER["plan"]
    if name not in plan:
        raise RuntimeError(f"report figure {name!r}: not in the plan a worker rebuilt from the run "
                           f"({', '.join(sorted(plan)) or 'empty'})")
    return draw_one(name, plan[name], Path(out), dpi, _WORKER["clipped"])


def draw_parallel(names: list[str], out: Path, dpi: int, workers: int,
                  rebuild: Callable[..., tuple[Plan, dict]], kwargs: dict, progress: bool) -> list[Drawn]:
    """Draw ``names`` in ``workers`` processes, each rebuilding the plan with ``rebuild(**kwargs)``."""
    with worker_pool(workers, initializer=_init_worker, initargs=(rebuild, kwargs)) as pool:
        futures = [pool.submit(_draw_named, n, str(out), dpi) for n in names]
        return [f.result() for f in progress_bar(futures, desc="report figures", unit="fig", enabled=progress)]
