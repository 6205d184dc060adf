"""The evaluate stage at the default population: local vs Ray with 1 and 2 workers on this machine,
and what a full-AVD study would cost on N machines (printed, never asserted).

Runs the default config's upstream stages if they are stale (the first time: the whole default
pipeline, ~8 min), then the evaluate stage three times (forced): ``run.executor = "local"``, then
``"ray"`` on a local Ray instance with ``ray_workers`` = 1 and 2, started just before the stage
(which joins it) and timed on its own. The three runs must give the same results.parquet and
summary.json (timings aside); the bench says so.

Per run it prints the stage's wall time and, from the executor's own records
(``pipeline.infra.executor.STATS``): the grid tasks, the wall time of the map call and the sum of the
tasks' own times measured inside them. From these:
  ratio              = local stage time / Ray stage time;
  overhead per task  = (map wall x slots - sum of task times) / tasks: scheduling, argument and
                       result transfer, and idle slots at the end (with 1 worker: pure overhead);
  fixed cost         = stage wall - map wall: Ray start and stop, the driver's serial work
                       (tracks, bootstrap, writing files), the same for every worker count.
Projection (on paper): tasks_full = tasks here x full_targets / targets here (same tracks,
settings and realizations per target); with t = mean task time measured with 2 workers (one core
per task, as on a cluster node running a task per core), o = overhead per task with 1 worker, and
serial = the driver's work outside the grid in the local run: its statistics (bootstrap; the
summary's ``timings_s.statistics``) scaled by the same factor, plus the rest (reading inputs,
tracks, the single-track sensitivity sweep and figures), which does not grow with the targets,
  T(N machines x c cores) = serial + ceil(tasks_full / (N c)) x (t + o).
Features likewise: crops_full x seconds per crop (this machine's features manifest) / (N c).

    python tests/bench/bench_ray.py [--full-targets 300] [--full-crops 40000] [--cores 16] [--set KEY=VALUE]
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load {one:.2f} (1 min) {five:.2f} (5 min) on {os.cpu_count()} cores"


def preloader():
    """A task that imports its ``modules`` and returns its process id: warms a worker before
    timing it. Made inside a function so that Ray ships it by value (this script is not an
    importable module on the workers)."""
    def preload(modules, item=None) -> int:
        import importlib
        import os

        for m in modules:
            importlib.import_module(m)
        return os.getpid()
    return preload


def _run_evaluate(base_cfg, executor: str, workers: int) -> dict:
    """One forced evaluate run. For Ray, the local instance (``workers`` CPUs) is started before
    the stage and stopped after it (the stage joins it), and both are timed on their own."""
    import dataclasses

    import pyarrow.parquet as pq

    from pipeline.infra import executor as ex
    from stages.framework.runner import ensure

    cfg = dataclasses.replace(base_cfg, run=dataclasses.replace(base_cfg.run, executor=executor, ray_workers=workers))
    before = _load()
    t0 = time.perf_counter()
    hold = ex.make_executor("ray", workers=workers) if executor == "ray" else None
    if hold is not None:
        # Worker processes up and the evaluation's modules imported: the grid then measures
        # scheduling, not Python start-up (which the start/stop column shows).
        pids = hold.map(preloader(), [None] * 4 * workers, shared=["pipeline.evaluation.grid.population", "stages.evaluate"])
        assert len(set(pids)) >= 1
    start = time.perf_counter() - t0
    del ex.STATS[:]
    t0 = time.perf_counter()
    ensure(cfg, "evaluate", force=True, device="cpu")
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    if hold is not None:
        hold.close()
    stop = time.perf_counter() - t0
    recs = [r for r in ex.STATS if r["executor"] == executor]
    ev = cfg.stage_dir("evaluate")
    summary = json.loads((ev / "summary.json").read_text())
    timings = summary.pop("timings_s", None) or {}
    return {"name": executor if executor == "local" else f"ray x{workers}", "wall": wall, "start": start + stop,
            "recs": recs, "table": pq.read_table(ev / "results.parquet"), "summary": summary, "timings": timings,
            "load": f"{before} / {_load()}"}


def _grid(run: dict) -> tuple[int, float, float, int]:
    """(tasks, map wall, sum of task times, slots) over the run's executor calls."""
    r = run["recs"]
    return (sum(x["tasks"] for x in r), sum(x["wall_s"] for x in r), sum(x["task_s"] for x in r),
            max((x["slots"] for x in r), default=1))


def _hms(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else (f"{s / 60:.1f} min" if s < 7200 else f"{s / 3600:.1f} h")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--full-targets", type=int, default=300,
                   help="targets in a full-AVD study (about 20 scans x 15 instances)")
    p.add_argument("--full-crops", type=int, default=40000, help="boxed AVD views to score in a full-AVD study")
    p.add_argument("--cores", type=int, default=16, help="cores per cluster machine")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, as for viewfuse (e.g. a smaller population for a quick look)")
    args = p.parse_args(argv if argv is not None else [])
    if importlib.util.find_spec("ray") is None:
        print("Ray is not installed (make venv-ray): bench skipped")
        return
    from pipeline.infra.config import merge, load_config, parse_override
    from stages.framework.runner import ensure, read_manifest

    over: dict = {"run": {"device": "cpu"}}
    for o in args.overrides:
        over = merge(over, parse_override(o))
    cfg = load_config(ROOT / "configs" / "synthetic.toml", over)
    print(f"default population in {cfg.run_dir}; upstream stages first if stale ({_load()})", flush=True)
    ensure(cfg, "models", device="cpu")
    preloader()(["pipeline.evaluation.grid.population", "pipeline.evaluation.statistics.engine", "stages.evaluate"])   # the local run starts warm too
    runs = [_run_evaluate(cfg, "local", 0), _run_evaluate(cfg, "ray", 1), _run_evaluate(cfg, "ray", 2)]
    local = runs[0]
    if not local["recs"]:
        print("the evaluate stage does not run its grid through the executor: nothing to compare")
        return
    same = all(r["table"].equals(local["table"]) and r["summary"] == local["summary"] for r in runs[1:])
    print(f"results.parquet and summary.json (timings aside) identical across the three runs: {same}")
    print(f"{'run':<9} {'stage s':>8} {'ratio':>6} {'+start/stop s':>13} {'tasks':>6} {'map s':>7} {'task sum s':>10} "
          f"{'overhead/task ms':>16} {'fixed s':>8}   machine load before / after")
    for r in runs:
        n, mwall, tsum, slots = _grid(r)
        over = (mwall * slots - tsum) / max(n, 1)
        print(f"{r['name']:<9} {r['wall']:8.1f} {local['wall'] / r['wall']:6.2f} {r['start']:13.1f} {n:6d} {mwall:7.1f} "
              f"{tsum:10.1f} {1000 * over:16.1f} {r['wall'] - mwall:8.1f}   {r['load']}")
    print("(stage s: the evaluate stage with Ray already running and its workers warm; +start/stop s: starting "
          "the local Ray instance, warming its workers and stopping it, paid once per stage when the stage "
          "starts Ray itself)")

    # Projection from the measured per-task times (see the module docstring).
    n, mwall, tsum, _ = _grid(runs[2])
    t = tsum / max(n, 1)
    over = max(0.0, (_grid(runs[1])[1] - _grid(runs[1])[2]) / max(_grid(runs[1])[0], 1))
    targets = len(local["summary"].get("population", {}).get("targets", [])) or 1
    scale = args.full_targets / targets
    tasks_full = math.ceil(n * scale)
    stats_s = float(local["timings"].get("statistics", 0.0))
    fixed = max(0.0, local["wall"] - _grid(local)[1] - stats_s)
    serial = stats_s * scale + fixed
    print(f"\nfull-AVD projection: {args.full_targets} targets = {scale:.0f} x the {targets} here -> {tasks_full} tasks "
          f"of {t:.2f} s (+ {1000 * over:.0f} ms overhead) = {tasks_full * t / 3600:.1f} CPU-hours; serial driver "
          f"part ~{_hms(serial)} (statistics {stats_s:.1f} s x {scale:.0f} + {fixed:.1f} s that does not grow)")
    fm = (read_manifest(cfg, "features") or {}).get("extra", {})
    per_crop = fm.get("timings", {}).get("avd_s", 0.0) / max(fm.get("avd_crops", 0), 1)
    print(f"features: {args.full_crops} crops x {per_crop * 1000:.0f} ms per crop (this machine, "
          f"{fm.get('torch_threads', '?')} threads, N_s = {fm.get('n_samples', '?')}) = "
          f"{args.full_crops * per_crop / 3600:.1f} machine-hours here")
    print(f"{'machines':>8} {'cores':>6} {'evaluate':>10} {'features':>10}")
    threads = max(int(fm.get("torch_threads", 1) or 1), 1)
    for N in (1, 2, 4, 8, 16, 32, 64):
        c = N * args.cores
        ev = serial + math.ceil(tasks_full / c) * (t + over)
        feat = args.full_crops * per_crop * threads / c
        print(f"{N:8d} {c:6d} {_hms(ev):>10} {_hms(feat):>10}")


if __name__ == "__main__":
    main(sys.argv[1:])
