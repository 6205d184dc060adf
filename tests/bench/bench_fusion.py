"""Fusion engine benchmarks (printed, never asserted).

1. Engine vs the literal Eq. 13-40 implementation on one workload (4 classes x 4 components,
   120 training views per class, K = 10, N_x = 50, N_s = 10): time ratio, goal >= 1000x.
2. Scaling in the track length: time per localization-sample trajectory for K = 5, 10, 20, 40
   and the empirical exponent between successive K (O(K³) per sample at most: <= 3).
3. The default randomized experiment's size (500 realizations x N_x = 100 x K = 10 x 4 classes x
   4 components x N_s = 10): wall time (goal < 30 s on the 2-core machine) and peak memory.

    python tests/bench/bench_fusion.py [--full-literal] [--realizations R]
By default the literal route is timed on 5 of the 50 localization samples and scaled by 10 (its
cost is exactly linear in N_x: one independent recursion per sample); ``--full-literal`` runs all
50 (several minutes).
"""
from __future__ import annotations

import argparse
import math
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.method.fusion import fuse_with_uncertainty  # noqa: E402
from pipeline.method.gp import GPClassModels  # noqa: E402
from tests.support.literal_paper import literal_uncertainty  # noqa: E402


def workload(seed=0, C=4, F=4, n_train=120):
    """Class models on a 120-view ring (BigBIRD's 3° turntable step) with realistic hyperparameters."""
    rng = np.random.default_rng(seed)
    th = np.linspace(0, 2 * np.pi, n_train, endpoint=False)
    XT = np.c_[np.cos(th), np.sin(th)]
    Y = [np.stack([0.2 + 0.1 * np.sin((f + 1) * th + c) + 0.01 * rng.standard_normal(n_train) for f in range(F)])
         for c in range(C)]
    return GPClassModels([f"class_{c}" for c in range(C)], list(range(F)), [XT] * C, Y,
                         np.array([[y.mean() for y in Yc] for Yc in Y]), rng.uniform(0.005, 0.02, (C, F)),
                         rng.uniform(0.3, 1.0, (C, F)), rng.uniform(1e-4, 1e-3, (C, F)))


def tracks(rng, R, Nx, K, S, F):
    est = rng.uniform(-2, 2, (R, 1, K, 2))
    x = est + 0.3 * rng.standard_normal((R, Nx, K, 2))
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return x, 0.2 + 0.05 * rng.standard_normal((R, K, S, F))


def best_of(fn, n=3):
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full-literal", action="store_true", help="literal route on all 50 samples (slow)")
    ap.add_argument("--realizations", type=int, default=500, help="size of part 3 (default 500)")
    args, _ = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    models = workload()
    models.factors()
    C, F = models.n_classes, models.n_components
    rng = np.random.default_rng(1)

    # 1. Engine vs literal on the same workload.
    K, Nx, S = 10, 50, 10
    X, Z = tracks(rng, 1, Nx, K, S, F)
    X, Z = X[0], Z[0]
    t_eng, p_eng = best_of(lambda: fuse_with_uncertainty(models, X, Z, progress=False))
    n_lit = Nx if args.full_literal else 5
    lit = (models.X, models.Y, models.mean, models.amplitude, models.length_scale, models.noise)
    t0 = time.perf_counter()
    p_lit = literal_uncertainty(*lit, X[:n_lit], Z)
    t_lit = (time.perf_counter() - t0) * (Nx / n_lit)
    p_sub = fuse_with_uncertainty(models, X[:n_lit], Z, progress=False)
    print(f"[1] workload: {C} classes x {F} components, 120 training views, K={K}, N_x={Nx}, N_s={S}")
    print(f"    engine  {t_eng * 1e3:9.2f} ms")
    print(f"    literal {t_lit:9.2f} s" + (f"  (measured on {n_lit} of {Nx} samples, scaled)" if n_lit < Nx else ""))
    print(f"    ratio   {t_lit / t_eng:9.0f}x   (goal >= 1000x)   max |engine - literal| = "
          f"{np.abs(p_sub - p_lit).max():.1e}" + ("" if n_lit < Nx else f", full-run diff {np.abs(p_eng - p_lit).max():.1e}"))

    # 2. Scaling with the track length.
    print("[2] time per localization-sample trajectory (4 x 4 GPs, N_s = 10, 2000 trajectories):")
    prev = None
    for K in (5, 10, 20, 40):
        X, Z = tracks(rng, 20, 100, K, 10, F)
        t, _ = best_of(lambda: fuse_with_uncertainty(models, X, Z, progress=False), n=2)
        per = t / (20 * 100)
        expo = "" if prev is None else f"   exponent vs K={prev[0]}: {math.log(per / prev[1]) / math.log(K / prev[0]):.2f}"
        print(f"    K={K:3d}: {per * 1e6:9.1f} us{expo}")
        prev = (K, per)

    # 3. The default randomized experiment's size.
    R = args.realizations
    X, Z = tracks(rng, R, 100, 10, 10, F)
    tracemalloc.start()
    t0 = time.perf_counter()
    post = fuse_with_uncertainty(models, X, Z, progress=False)
    t = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    assert post.shape == (R, 10, C) and np.all(np.isfinite(post))
    print(f"[3] randomized experiment size: {R} realizations x N_x=100 x K=10 x {C}x{F} GPs x N_s=10")
    print(f"    {t:6.2f} s (goal < 30 s{' at 500 realizations' if R != 500 else ''})   "
          f"peak traced memory {peak / 2**20:.0f} MiB, process max RSS {rss:.0f} MiB")


if __name__ == "__main__":
    main()
