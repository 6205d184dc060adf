"""The evaluate stage's planning part: build the tasks, run them on the executor, write
``evaluate/planning.parquet`` (one row per target, start, setting, planner and step) and return
the summary's ``planning`` block (with the decision times and one example path for the map)."""
from __future__ import annotations

import time

import numpy as np
import pandas as pd

from pipeline.infra.cache import atomic_path
from pipeline.planning.population import run_task
from pipeline.planning.summary import planning_block, step_rows


def episode_table(tasks, results) -> tuple[pd.DataFrame, list[float]]:
    """The per-step rows of every episode and the info-gain planner's decision times (s)."""
    parts, times = [], []
    for task, res in zip(tasks, results):
        w = task.world
        for setting, planner, ep in res:
            key = {"target": w.target, "scan": w.scan, "start": task.start, "setting": setting, "planner": planner}
            parts.append(step_rows(key, ep.log_post, ep.measured, ep.nodes, w.truth, task.confidence))
            if planner == "info_gain":
                times += ep.decision_s
    return pd.concat(parts, ignore_index=True), times


def example_path(tasks, results) -> dict:
    """The first task's biased info-gain episode next to its fixed track, for the floor-plan map:
    the views' true positions, the object, and every view of the target in that scan."""
    task, res = tasks[0], results[0]
    w = task.world
    eps = {p: ep for s, p, ep in res if s == "biased"}

    def xy(nodes):
        return [[round(float(v), 4) for v in w.xy[n]] for n in nodes]

    return {"target": w.target, "scan": w.scan, "start": task.start, "setting": "biased",
            "object_xy": [float(v) for v in w.obj_xy], "views_xy": xy(sorted(w.xy)),
            "paths": {p: {"nodes": list(eps[p].nodes), "xy": xy(eps[p].nodes)} for p in ("info_gain", "fixed")
                      if p in eps}}


def write_table(table: pd.DataFrame, path) -> None:
    with atomic_path(path) as tmp:
        table.to_parquet(tmp, index=False)


def read_table(path) -> pd.DataFrame:
    return pd.read_parquet(path)


def run_planning(cfg, tasks: list, banks, executor, out_path) -> dict:
    """Every planning episode of the run (``tasks``, from ``population.build_tasks``, made before an
    executor's workers fork so that they inherit them); writes the table to ``out_path``, returns
    the block."""
    ev, plan = cfg.evaluate, cfg.plan
    t0 = time.perf_counter()
    if not tasks:
        return {"skipped": "no target has a start node"}, {}
    results = list(executor.imap(run_task, tasks, shared=banks, desc="evaluate: planning", unit="start",
                                 total=len(tasks)))
    table, times = episode_table(tasks, results)
    run_s = time.perf_counter() - t0
    write_table(table, out_path)
    block = planning_block(table, tasks[0].planners, plan.budget, plan.confidence, ev.bootstrap, ev.seed)
    ms = np.asarray(times) * 1e3
    block["example"] = example_path(tasks, results)
    # Wall times go to the summary's timings_s (they differ run to run; the block is deterministic).
    timings = {"planning_episodes": run_s, "planning_statistics": time.perf_counter() - t0 - run_s,
               "planning_decisions": float(len(ms))}
    if len(ms):
        timings.update(planning_decision_ms_median=float(np.median(ms)), planning_decision_ms_p90=float(np.percentile(ms, 90)))
    return block, timings
