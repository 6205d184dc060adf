"""Leave-one-target-out: the jackknife-after-bootstrap route (the draws already made,
``pipeline.evaluation.statistics.hierarchy.leave_one_out``) against the previous one that
re-resampled every (T - 1)-target subset (tests/support/loto_reference.py), measured in one run.

Workload: ``--targets`` targets (default 75, configs/real_full.toml's COIL objects) with 2-6
tracks, one metric's paired difference, ``--boot`` draws (2000, ``evaluate.bootstrap``). Printed:
each route's seconds, their ratio, the largest difference of the left-out values (the same
statistic: ~0) and the machine's load.

    python tests/bench/bench_loto.py [--targets T] [--boot B]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.evaluation.statistics import resampler  # noqa: E402
from pipeline.evaluation.statistics.hierarchy import Hierarchy, leave_one_out  # noqa: E402
from tests.support import loto_reference as REF  # noqa: E402


def workload(n_targets: int, n_boot: int, seed=0):
    rng = np.random.default_rng(seed)
    rows = [{"target": f"t{t:03d}", "track": j} for t in range(n_targets) for j in range(int(rng.integers(2, 7)))]
    h = Hierarchy({"run": pd.DataFrame(rows)}, n_boot, seed)
    return h, rng.normal(0.02, 0.2, h.target_rs.shape)


def jackknife(h, v, pool="mean", higher=True) -> dict:
    """The engine's call (``engine``: full estimate, left-out points, the draws' first T - 1 slots)."""
    rs = h.target_rs
    return leave_one_out(h, rs.estimate(v, pool), rs.leave_one_out_points(v, pool),
                         rs.draws(v, pool, slots=rs.shape[1] - 1), higher)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=75)
    ap.add_argument("--boot", type=int, default=2000)
    args, _ = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    h, v = workload(args.targets, args.boot)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    new = jackknife(h, v)
    t_new = time.perf_counter() - t0
    resampler._cached.cache_clear()            # the old route's subsets get no draws cached by a previous run
    t0 = time.perf_counter()
    old = REF.leave_one_out(h, v, "mean", True)
    t_old = time.perf_counter() - t0
    dv = max(abs(new["loto_min"] - old["loto_min"]), abs(new["loto_max"] - old["loto_max"]))
    print(f"leave-one-target-out, {args.targets} targets x {args.boot} draws: re-resampling {t_old:.2f} s, "
          f"from the draws made {t_new:.3f} s, ratio {t_old / max(t_new, 1e-9):.0f}x; left-out range differs by "
          f"{dv:.1e}; flips {len(old['loto_flips'])} (old) / {len(new['loto_flips'])} (new); load average "
          f"{load0:.1f} -> {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    return {"route": f"leave-one-target-out, {args.targets} targets: jackknife-after-bootstrap against re-resampling",
            "previous_s": t_old, "current_s": t_new}


if __name__ == "__main__":
    main()
