"""The fusion engine against the reference engine (tests/support/reference_fusion.py), side by side.

Workload: 4 classes x 4 components, 120 training views per class (a full turntable
ring, as BigBIRD's: the basis route's diagonal form applies), K = 9, N_s = 10, 40 realizations x
N_x = 50 trajectories per call. Both engines run interleaved, several rounds,
in one process: the ratio is the number to read, since other processes on the machine slow both
alike. Printed per thread count: With Uncertainty trajectories per second (best round, wall clock
and CPU time) of each engine and their ratio (goal >= 6x, 20,000 trajectories/s), the largest log
posterior difference, Model Based's ratio; the same at short length scales (ℓ 0.1-0.3, like the
default run's fits: Fourier orders near the number of training views, less to gain); and the
torch path (CPU torch; the GPU when CUDA is present, else "GPU: unmeasured").

    python tests/bench/bench_engine.py [--rounds N]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.method import engine  # noqa: E402
from pipeline.method.gp import GPClassModels  # noqa: E402
from pipeline.method.fusion import engine_device, fuse_model_based, fuse_with_uncertainty  # noqa: E402
from tests.support import reference_fusion as ref  # noqa: E402
from tests.bench.bench_fusion import workload  # noqa: E402


def case(R=40, n_x=50, K=9, S=10, F=4, seed=0):
    rng = np.random.default_rng(seed)
    th = rng.uniform(-np.pi, np.pi, (R, 1, K)) + 0.3 * rng.standard_normal((R, n_x, K))
    X = np.stack([np.cos(th), np.sin(th)], -1)
    return X, 0.2 + 0.05 * rng.standard_normal((R, K, S, F))


def rounds(fns: dict, n: int) -> dict:
    """Best (wall, cpu) seconds of each function over n interleaved rounds."""
    best = {k: [np.inf, np.inf] for k in fns}
    for _ in range(n):
        for k, f in fns.items():
            w, c = time.perf_counter(), time.process_time()
            f()
            best[k][0] = min(best[k][0], time.perf_counter() - w)
            best[k][1] = min(best[k][1], time.process_time() - c)
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    args, _ = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    models = workload()
    models.factors()
    X, Z = case()
    R, n_x = X.shape[:2]
    n = R * n_x
    routes = engine.plan(models).routes()
    print(f"workload: 4 classes x 4 components, 120 training views, K=9, N_s=10, {R} x N_x={n_x} = {n} trajectories; "
          f"routes: {routes['basis']} basis (P = {min(routes['P'], default=0)}..{max(routes['P'], default=0)}; "
          f"{routes['diagonal']} of them diagonal), {routes['exact']} exact")
    a = fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    b = ref.fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    print(f"max |log posterior difference| vs reference: {np.max(np.abs(a - b)):.1e} "
          f"(relative {np.max(np.abs(a - b) / np.maximum(1, np.abs(b))):.1e}; tests hold it <= 1e-9)")
    for threads in (1, 2):
        ratio_line(models, X, Z, n, threads, args.rounds)
    # The default run's fits are shorter (median ℓ about 0.2): P near N, less to gain.
    short = GPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                          np.random.default_rng(3).uniform(0.1, 0.3, models.length_scale.shape), models.noise)
    rs = engine.plan(short).routes()
    ps = rs["P"]
    print(f"short length scales (ℓ 0.1..0.3, P = {min(ps, default=0)}..{max(ps, default=0)}; {rs['diagonal']} diagonal, "
          f"{rs['basis'] - rs['diagonal']} sparse with P > N, {rs['exact']} exact):")
    ratio_line(short, X, Z, n, 2, args.rounds)
    torch_lines(models, X, Z, n, n_x)


def ratio_line(models, X, Z, n, threads, n_rounds) -> None:
    kw = dict(return_log=True, progress=False, threads=threads)
    best = rounds({"engine": lambda: fuse_with_uncertainty(models, X, Z, **kw),
                   "reference": lambda: ref.fuse_with_uncertainty(models, X, Z, **kw),
                   "mb engine": lambda: fuse_model_based(models, X[:, 0], Z.mean(2), **kw),
                   "mb reference": lambda: ref.fuse_model_based(models, X[:, 0], Z.mean(2), **kw)}, n_rounds)
    e, r = best["engine"], best["reference"]
    print(f"threads={threads}: With Uncertainty engine {n / e[0]:8.0f} traj/s (CPU-time {n / e[1]:8.0f}/s), "
          f"reference {n / r[0]:7.0f} traj/s (CPU-time {n / r[1]:7.0f}/s): "
          f"ratio {r[0] / e[0]:.2f}x wall, {r[1] / e[1]:.2f}x CPU   (goal >= 6x, 20,000 traj/s)")
    me, mr = best["mb engine"], best["mb reference"]
    print(f"           Model Based ratio {mr[0] / me[0]:.2f}x wall, {mr[1] / me[1]:.2f}x CPU")


def torch_lines(models, X, Z, n, n_x) -> None:
    try:
        import torch
    except ImportError:  # pragma: no cover
        print("torch: not installed")
        return
    small = (X[:10], Z[:10])
    with engine_device("torch-cpu"):
        t = rounds({"torch-cpu": lambda: fuse_with_uncertainty(models, *small, return_log=True, progress=False)}, 2)
    print(f"torch on the CPU: {small[0].shape[0] * n_x / t['torch-cpu'][0]:.0f} traj/s (a test path, not a fast one)")
    if torch.cuda.is_available():
        with engine_device("cuda"):
            fuse_with_uncertainty(models, *small, return_log=True, progress=False)   # warm-up
            g = rounds({"gpu": lambda: fuse_with_uncertainty(models, X, Z, return_log=True, progress=False,
                                                             block=1 << 24)}, 3)["gpu"][0]
        c = rounds({"cpu": lambda: fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)}, 3)["cpu"][0]
        print(f"GPU ({torch.cuda.get_device_name(0)}): {n / g:.0f} traj/s vs this machine's CPU engine "
              f"{n / c:.0f} traj/s: ratio {c / g:.2f}x")
    else:
        print("GPU: unmeasured (no CUDA device on this machine)")


if __name__ == "__main__":
    main()
