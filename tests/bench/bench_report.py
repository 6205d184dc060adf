"""The report's figures: drawn in one process against drawn at once in worker processes
(``reports.main.figure_pool``), measured in one run on the same generated full-scale-shaped run.

Workload (``tests/support/report_scale.py``): ``--targets`` targets (default 75, as the real
chains), 3 tracks each, 5 methods, 3 randomized settings, 8 steps, 4 realizations. Printed: each
route's wall and CPU seconds (this process and its workers together), the ratio of walls, whether
the two routes wrote the same PNG bytes, the workers used and the machine's load before and after
(the wall ratio only shows the parallel gain where cores are free; on a loaded machine compare CPU).

    python tests/bench/bench_report.py [--targets T] [--workers N] [--keep DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from reports.main.page import build_main_report  # noqa: E402
from tests.support.report_scale import write_scaled_run  # noqa: E402


def _cpu() -> float:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _render(run: Path, out: Path, workers: int) -> tuple[float, float, list[str]]:
    t0, c0 = time.perf_counter(), _cpu()
    res = build_main_report(run, out, run_name="bench", progress=False, n_boot=200, strict="contradictions",
                            workers=workers)
    return time.perf_counter() - t0, _cpu() - c0, res.figures


def _pngs(out: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.glob("*.png"))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=75)
    ap.add_argument("--workers", type=int, default=2, help="the parallel route's processes (default 2)")
    ap.add_argument("--keep", default="", help="a folder for the generated run and both reports (default: a "
                    "temp one); a run generated there before is reused")
    args, _ = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep or tmp)
        if not (root / "run" / "evaluate" / "summary.json").exists():   # --keep: made by an earlier run
            t0 = time.perf_counter()
            facts = write_scaled_run(root / "run", targets=args.targets)
            print(f"generated run: {args.targets} targets, {facts['T'] * facts['tracks']} tracks, "
                  f"{len(facts['rows'])} rows in {time.perf_counter() - t0:.0f} s", flush=True)
        load0 = os.getloadavg()
        w1, c1, figs = _render(root / "run", root / "serial", 1)
        wn, cn, _ = _render(root / "run", root / "parallel", args.workers)
        same = _pngs(root / "serial") == _pngs(root / "parallel")
        load1 = os.getloadavg()
    print(f"report, {len(figs)} figures: serial {w1:.1f} s wall / {c1:.1f} s CPU; {args.workers} workers "
          f"{wn:.1f} s wall / {cn:.1f} s CPU; wall ratio {w1 / max(wn, 1e-9):.2f}x; PNGs identical: {same}")
    print(f"machine: {os.cpu_count()} cores, load {load0[0]:.1f} before, {load1[0]:.1f} after "
          f"(1-minute averages)")


if __name__ == "__main__":
    main()
