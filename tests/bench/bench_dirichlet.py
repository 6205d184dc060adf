"""Cost per population cell of each method, the Dirichlet beside the others (printed, never asserted).

A cell of the default config (configs/synthetic.toml): K = 9 views, N_s = 10 dropout samples of a
D = 12 probability vector, 4 candidates x 4 GP components on 120-view rings; the settings are the
biased experiment (1 realization, N_x = 50) and three randomized ones (30 realizations, N_x = 25).
With Uncertainty and Model Based run once per realization (their posteriors depend on the pose
estimates); Simple Bayes and the Dirichlet ignore the poses and run once per cell
(``pipeline.evaluation.grid.population.run_cell``). Also: the Dirichlet's cost against N_ss, and the
models stage's Dirichlet fit (12 classes x 120 vectors).

    python tests/bench/bench_dirichlet.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.method.dirichlet import DirichletModels, fit_class_dirichlets  # noqa: E402
from pipeline.method.dirichlet_fusion import fuse_dirichlet  # noqa: E402
from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty, simple_bayes  # noqa: E402
from tests.bench.bench_fusion import workload  # noqa: E402

K, S, D, C = 9, 10, 12, 4
SETTINGS = ((1, 50), (30, 25), (30, 25), (30, 25))      # (realizations, N_x) per setting


def best_of(fn, n=3) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None) -> None:
    rng = np.random.default_rng(0)
    gp = workload(C=C, F=4)
    gp.factors()
    probs = rng.dirichlet(np.full(D, 0.3), size=(K, S))                        # (K, N_s, D)
    drop = probs[:, :, :4]
    dm = DirichletModels([f"class_{c}" for c in range(C)], rng.uniform(0.1, 3.0, (C, D)), floor=1e-6)
    inputs = {}
    for r, nx in SETTINGS:
        th = rng.uniform(-np.pi, np.pi, (r, nx, K))
        inputs[(r, nx)] = np.stack([np.cos(th), np.sin(th)], -1)

    def wu():
        for r, nx in SETTINGS:
            fuse_with_uncertainty(gp, inputs[(r, nx)], np.broadcast_to(drop, (r,) + drop.shape), return_log=True,
                                  progress=False)

    def mb():
        for r, nx in SETTINGS:
            fuse_model_based(gp, inputs[(r, nx)][:, 0], np.broadcast_to(drop.mean(1), (r, K, 4)), return_log=True,
                             progress=False)

    costs = {
        "With Uncertainty": best_of(wu),
        "Model Based": best_of(mb),
        "Simple Bayes": best_of(lambda: simple_bayes(probs[:, :, :C].mean(axis=1), return_log=True), n=20),
        "Dirichlet (N_ss = 100)": best_of(lambda: fuse_dirichlet(dm, probs, n_ss=100, rng=np.random.default_rng(1)),
                                          n=10),
    }
    print(f"[1] cost per cell (K = {K}, N_s = {S}, D = {D}, {C} candidates, settings {SETTINGS} as (R, N_x)); "
          "timings on a shared machine, compare within this run:")
    ref = costs["With Uncertainty"]
    for name, t in costs.items():
        print(f"    {name:24s} {t * 1e3:9.2f} ms   ({t / ref:9.3g} x With Uncertainty)")
    print("[2] Dirichlet cost per cell against N_ss:")
    for n_ss in (10, 100, 1000):
        t = best_of(lambda: fuse_dirichlet(dm, probs, n_ss=n_ss, rng=np.random.default_rng(1)), n=5)
        print(f"    N_ss = {n_ss:5d}: {t * 1e3:8.2f} ms")
    vectors = {f"class_{c}": rng.dirichlet(rng.uniform(0.05, 2.0, D), size=120) for c in range(12)}
    t0 = time.perf_counter()
    _, diags = fit_class_dirichlets(vectors, floor=1e-6, tol=1e-10, max_iter=20000)
    t = time.perf_counter() - t0
    print(f"[3] Dirichlet fits, 12 classes x 120 vectors (D = {D}): {t * 1e3:.1f} ms, fixed-point iterations "
          f"{min(d['iterations'] for d in diags)}-{max(d['iterations'] for d in diags)}, "
          f"{sum(not d['converged'] for d in diags)} not converged")


if __name__ == "__main__":
    main()
