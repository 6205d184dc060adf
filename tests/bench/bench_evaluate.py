"""The evaluate stage at the default population, and the fusion engine's throughput.

1. The evaluate stage on the default config (configs/synthetic.toml): upstream stages are brought
   up to date first (reused when the main job already ran), then evaluate runs forced and timed.
   Printed: wall time (goal: under 3 minutes on the 2-core machine), the population's size, the
   share spent in the grid vs the statistics, and the grid's trajectories per second.
2. The engine alone: With Uncertainty trajectories per second at K = 9 and K = 10 (4 classes x
   4 components, 120 training views, N_s = 10), the figure the issue sizes the defaults by.
3. The paper-grade preset (configs/paper_grade.toml: 500 realizations x N_x = 100 per σ): its
   evaluate stage, forced, in a child process, reusing the default run's upstream stages (linked
   into artifacts/paper_grade/); wall time (goal <= 10 min on the 2-core machine), the child's
   peak RSS (goal <= 4 GB) and the stage's time split (grid, of it the With Uncertainty fusion;
   per-cell metrics and rows; writing; statistics; showcase).

    python tests/bench/bench_evaluate.py [--config FILE] [--skip-stage] [--skip-paper-grade]
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
    from stages.framework.runner import ensure, read_manifest

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
    grids = 1 + sum(a != "attribution" for a in pop.get("ablations", {}))   # each ablation reruns the grid
    print(f"  {traj} With Uncertainty trajectories per grid x {grids}; " + split(tim, traj * grids))
    variants = [a for a in pop.get("ablations", {})]
    print(f"  variants on: {', '.join(variants) or 'none'} (attribution = With Uncertainty poses only / dropout "
          "only; each evaluate.ablations entry reruns the whole grid)")
    m = read_manifest(cfg, "evaluate")
    print(f"  manifest: {m['summary']}")


def paper_grade(config: str) -> None:
    import os
    import subprocess

    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure

    base = load_config(config)
    ensure(base, "models")
    pg_path = ROOT / "configs" / "paper_grade.toml"
    pg = load_config(pg_path)
    for stage in ("data", "classifier", "features", "models"):
        src, dst = base.stage_dir(stage), pg.stage_dir(stage)
        if pg.section_hash(stage) != base.section_hash(stage):
            continue  # a changed preset: let the child compute its own
        if not (dst.exists() or dst.is_symlink()):
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(os.path.relpath(src, dst.parent), dst, target_is_directory=True)
    child = ("import resource, sys\n"
             "from pipeline.infra.config import load_config\n"
             "from stages.framework.runner import ensure\n"
             f"ensure(load_config({str(pg_path)!r}), 'evaluate', force=True)\n"
             "print('MAXRSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", child], cwd=ROOT, env=env, capture_output=True, text=True)
    took = time.perf_counter() - t0
    if out.returncode:
        print(f"paper-grade evaluate FAILED ({took:.0f} s):\n{out.stderr[-3000:]}")
        return
    rss = [int(line.split()[1]) for line in out.stdout.splitlines() if line.startswith("MAXRSS_KB")][0]
    summary = json.loads((pg.stage_dir("evaluate") / "summary.json").read_text())
    pop, tim = summary["population"], summary["timings_s"]
    traj = sum(s["realizations"] * s["n_loc_samples"] for s in pop["settings"]) * pop["n_tracks"]
    print(f"paper-grade evaluate (configs/paper_grade.toml): {took:.0f} s wall incl. start-up "
          f"(goal <= 600 s), peak RSS {rss / 2**20:.2f} GiB (goal <= 4 GiB); {traj} With Uncertainty trajectories")
    print("  " + split(tim, traj))


def split(tim: dict, traj: int) -> str:
    """The evaluate stage's time split from summary.json's timings_s (seconds)."""
    wu = tim.get("population_with_uncertainty", 0.0)
    total = sum(tim.get(k, 0.0) for k in ("domain_fit", "population", "cell_reduce", "statistics", "writing",
                                           "gp_models", "sensitivity", "bias_maps"))
    showcase = sum(tim.get(k, 0.0) for k in ("gp_models", "sensitivity", "bias_maps"))
    mb = tim.get("population_model_based", 0.0)
    return (f"grid {tim['population']:.0f} s (With Uncertainty fusion {wu:.0f} s = {wu / max(total, 1e-9):.0%} of the "
            f"stage, {traj / max(wu, 1e-9):.0f} trajectories/s; Model Based {mb:.0f} s), "
            f"per-cell metrics and rows {tim.get('cell_reduce', 0.0):.0f} s, writing {tim.get('writing', 0.0):.0f} s, "
            f"statistics {tim['statistics']:.0f} s, showcase {showcase:.0f} s, test-domain fit "
            f"{tim.get('domain_fit', 0.0):.0f} s")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "synthetic.toml"))
    ap.add_argument("--skip-stage", action="store_true", help="only the engine throughput")
    ap.add_argument("--skip-paper-grade", action="store_true", help="not the paper-grade evaluate (minutes)")
    args = ap.parse_args(argv if argv is not None else [])
    for K in (9, 10):
        print(f"engine: With Uncertainty at K = {K}: {engine_throughput(K):.0f} trajectories/s", flush=True)
    if not args.skip_stage:
        stage(args.config)
        if not args.skip_paper_grade:
            paper_grade(args.config)


if __name__ == "__main__":
    main(sys.argv[1:])
