"""View-planning benchmarks (printed, never asserted; docs/benchmarks.md).

1. One planning decision of the information-gain planner at the default sizes: 4 candidate classes
   x 4 components (120-view training rings), N_x = 50 localization samples (evaluate.biased's;
   the randomized setting has 25), plan.eig_samples = 64 draws per class, every candidate of one
   move on an AVD-like graph (12 headings per stop): median and 90th percentile over the decisions
   of several episodes, on 2 threads. Goal: median <= 50 ms.
2. One belief update (the fusion engine on the whole history) at K = 1..10.
3. The evaluate stage's planning seconds of the default run, where its summary.json exists
   (artifacts/synthetic/evaluate/summary.json): goal <= 120 s added.

    python tests/bench/bench_planning.py
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pipeline.method.gp import GPClassModels
from pipeline.planning.belief import Belief
from pipeline.planning.eig import RingTable, standard_draws
from pipeline.planning.episode import run_episode
from pipeline.planning.planners import InfoGain
from tests.pipeline.planning.ring import grid_world


def class_models(C=4, F=4, n_train=120, seed=0) -> GPClassModels:
    rng = np.random.default_rng(seed)
    th = np.linspace(0, 2 * np.pi, n_train, endpoint=False)
    X = np.c_[np.cos(th), np.sin(th)]
    Y = [np.stack([0.25 + 0.1 * np.sin((f + 1) * th + c) + 0.01 * rng.standard_normal(n_train) for f in range(F)])
         for c in range(C)]
    return GPClassModels([f"c{c}" for c in range(C)], list(range(F)), [X] * C, Y, mean=np.full((C, F), 0.25),
                         amplitude=np.full((C, F), 0.01), length_scale=np.full((C, F), 0.5),
                         noise=np.full((C, F), 1e-3))


def main() -> None:
    from threadpoolctl import threadpool_limits

    models, world = class_models(), grid_world()
    eps = standard_draws(64, 4, 0)
    t0 = time.perf_counter()
    table = RingTable(models)
    table_s = time.perf_counter() - t0
    times, updates, n_cands = [], {k: [] for k in range(1, 11)}, []
    with threadpool_limits(2):
        starts = sorted(world.xy)[::max(1, len(world.xy) // 12)][:12]
        for i, start in enumerate(starts):
            b = Belief(models, world, bias=(-0.3, 0.2), sigma=0.3, n_x=50, key=(i,))
            planner = InfoGain(eps, table)
            orig = planner.choose

            def timed(belief, cands, rng, orig=orig):
                n_cands.append(len(cands))
                return orig(belief, cands, rng)

            planner.choose = timed
            ep = run_episode(b, planner, start, budget=10, confidence=None, horizon=1, rng=np.random.default_rng(i))
            times += ep.decision_s
            b2 = Belief(models, world, bias=(-0.3, 0.2), sigma=0.3, n_x=50, key=(i,))
            for k, n in enumerate(ep.nodes, start=1):
                t0 = time.perf_counter()
                b2.update(n)
                updates[k].append(time.perf_counter() - t0)
    ms = np.asarray(times) * 1e3
    print(f"predictive table (2048 angles, 16 GPs): {table_s:.2f} s, once per candidate set")
    print(f"planning decision (4 classes x 4 components, N_x = 50, 64 draws/class, "
          f"{np.mean(n_cands):.1f} candidates on average, 2 threads): median {np.median(ms):.1f} ms, "
          f"p90 {np.percentile(ms, 90):.1f} ms over {len(ms)} decisions (goal: median <= 50 ms)")
    print("belief update (fusion engine, whole history), median ms by K: "
          + ", ".join(f"K={k}: {1e3 * np.median(v):.1f}" for k, v in updates.items() if v))
    summary = ROOT / "artifacts" / "synthetic" / "evaluate" / "summary.json"
    if summary.is_file():
        s = json.loads(summary.read_text())
        t = s.get("timings_s", {}).get("planning")
        d = (s.get("planning") or {}).get("decision_ms") or {}
        print(f"default evaluate run: planning added {t} s (goal <= 120 s); its decisions: median "
              f"{d.get('median')} ms over {d.get('n')}")
    else:
        print(f"no default run at {summary}: run `make evaluate` for the stage's planning time")


if __name__ == "__main__":
    main()
