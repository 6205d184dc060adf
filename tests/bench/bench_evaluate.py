"""The evaluate stage at the default population, and the fusion engine's throughput.

1. The evaluate stage on the default config (configs/synthetic.toml): upstream stages are brought
   up to date first (reused when the main job already ran), then evaluate runs forced and timed.
   Printed: wall time (goal: under 3 minutes on the 2-core machine), the population's size, the
   share spent in the grid vs the statistics, and the grid's trajectories per second.
2. The engine alone: With Uncertainty trajectories per second at K = 9 and K = 10 (4 classes x
   4 components, 120 training views, N_s = 10), the figure the issue sizes the defaults by.

    python tests/bench/bench_evaluate.py [--config FILE] [--skip-stage]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def engine_throughput(K: int, R: int = 20, n_x: int = 50) -> float:
    from pipeline.method.fusion import fuse_with_uncertainty
    from tests.bench.bench_fusion import workload

    models = workload()
    rng = np.random.default_rng(0)
    th = rng.uniform(-np.pi, np.pi, (R, n_x, K))
    X = np.stack([np.cos(th), np.sin(th)], -1)
    drop = 0.2 + 0.05 * rng.standard_normal((R, K, 10, models.n_components))
    fuse_with_uncertainty(models, X[:2], drop[:2], return_log=True, progress=False)   # warm-up
    t0 = time.perf_counter()
    fuse_with_uncertainty(models, X, drop, return_log=True, progress=False)
    return R * n_x / (time.perf_counter() - t0)


def stage(config: str) -> None:
    from pipeline.infra.config import load_config
    from stages.runner import ensure, read_manifest

    cfg = load_config(config)
    keys: dict = {}
    t0 = time.perf_counter()
    ensure(cfg, "models", _keys=keys)
    print(f"upstream stages ready in {time.perf_counter() - t0:.1f} s", flush=True)
    t0 = time.perf_counter()
    ensure(cfg, "evaluate", force=True, _keys=keys)
    took = time.perf_counter() - t0
    summary = json.loads((cfg.stage_dir("evaluate") / "summary.json").read_text())
    pop, tim = summary["population"], summary["timings_s"]
    traj = sum(s["realizations"] * s["n_loc_samples"] for s in pop["settings"]) * pop["n_tracks"]
    print(f"evaluate stage: {took:.1f} s wall (goal < 180 s) for {pop['n_targets']} targets x {pop['n_tracks']} tracks "
          f"x {len(pop['settings'])} settings ({pop['n_cells']} cells), bootstrap {pop['bootstrap']}")
    print(f"  grid {tim['population']:.1f} s ({traj} With Uncertainty trajectories: "
          f"{traj / tim['population']:.0f} trajectories/s incl. Model Based and Simple Bayes), "
          f"statistics {tim['statistics']:.1f} s, single-track figures "
          f"{sum(tim.get(k, 0.0) for k in ('sensitivity', 'bias_maps', 'gp_models')):.1f} s, "
          f"test-domain fit {tim.get('domain_fit', 0.0):.1f} s")
    variants = [a for a in pop.get("ablations", {})]
    print(f"  variants on: {', '.join(variants) or 'none'} (attribution = With Uncertainty poses only / dropout "
          "only; each evaluate.ablations entry reruns the whole grid)")
    m = read_manifest(cfg, "evaluate")
    print(f"  manifest: {m['summary']}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "synthetic.toml"))
    ap.add_argument("--skip-stage", action="store_true", help="only the engine throughput")
    args = ap.parse_args(argv if argv is not None else [])
    for K in (9, 10):
        print(f"engine: With Uncertainty at K = {K}: {engine_throughput(K):.0f} trajectories/s", flush=True)
    if not args.skip_stage:
        stage(args.config)


if __name__ == "__main__":
    main(sys.argv[1:])
