"""The models stage's GP fits: scikit-learn one at a time (the previous route) against every fit at
once (``pipeline/method/gp_batch.py``), on the same fits in one run (printed, never asserted).

The fits are a category bank's shape (configs/real_category.toml): each class holds several
instances' views at the same 16 azimuths (``--instances`` x ``--azimuths`` inputs; ``--instances 1 --azimuths 72``: distinct views, as an
instance-level COIL class), ``--components`` score
components a class, the config's bounds, hyperpriors and restarts; targets are generated
(viewpoint-dependent score series plus noise). The old route is timed as the stage runs it and
also with one BLAS thread (on a loaded machine its default BLAS threads spin against each other);
the batched route always runs with one. Prints the machine's load, both wall times, the ratio and
the largest loss of the batched optimum against scikit-learn's (LML + log prior; should be <= 1e-6).

    python tests/bench/bench_gp.py --classes 3 --components 4 --instances 8
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.method.gp_fit import fit_class_models  # noqa: E402


def workload(classes: int, components: int, instances: int, azimuths: int = 16, seed: int = 0):
    rng = np.random.default_rng(seed)
    th = np.tile(np.linspace(0, 2 * np.pi, azimuths, endpoint=False), instances)
    X = np.c_[np.cos(th), np.sin(th)]
    Ys = []
    for _ in range(classes):
        Ys.append(np.stack([rng.uniform(0, 0.3) * np.sin(rng.integers(1, 4) * th + rng.uniform(0, 6))
                            + rng.uniform(0, 0.5) + rng.normal(0, 10 ** rng.uniform(-2.5, -0.7), len(th))
                            for _ in range(components)]))
    return [X] * classes, Ys


def timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def main(argv=None) -> dict:
    from threadpoolctl import threadpool_limits

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--classes", type=int, default=3)
    ap.add_argument("--components", type=int, default=4)
    ap.add_argument("--instances", type=int, default=8)
    ap.add_argument("--azimuths", type=int, default=16, help="distinct views a class (real.toml's COIL rings: 72)")
    ap.add_argument("--skip-default-threads", action="store_true", help="time the old route with one BLAS thread only")
    a = ap.parse_args(argv if argv is not None else [])
    Xs, Ys = workload(a.classes, a.components, a.instances, a.azimuths)
    names, comps = [f"c{i}" for i in range(a.classes)], list(range(a.components))

    def fit(route):
        return fit_class_models(Xs, Ys, names, comps, route=route, progress=False)

    load0 = os.getloadavg()
    for route in ("batch", "sklearn"):   # imports and first-call costs out of the timing
        fit_class_models(Xs[:1], [Ys[0][:1]], names[:1], comps[:1], route=route, restarts=0, progress=False)
    (new, dnew), t_new, c_new = timed(lambda: fit("batch"))
    with threadpool_limits(1, user_api="blas"):
        (ref, dref), t_one, c_one = timed(lambda: fit("sklearn"))
    t_def = c_def = None
    if not a.skip_default_threads:
        _, t_def, c_def = timed(lambda: fit("sklearn"))
    load1 = os.getloadavg()
    gap = min((b["log_marginal_likelihood"] + b["log_prior"]) - (r["log_marginal_likelihood"] + r["log_prior"])
              for b, r in zip(dnew, dref))
    n = a.classes * a.components
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{load0[0]:.2f} before, {load1[0]:.2f} after")
    print(f"{n} fits ({a.classes} classes x {a.components} components, {a.azimuths * a.instances} views each ({a.azimuths} distinct), "
          f"{dnew[0]['restarts']} restarts)")
    print(f"    scikit-learn, 1 BLAS thread      {t_one:8.2f} s wall {c_one:8.2f} s CPU   ({t_one / n:.3f} s a fit)")
    if t_def is not None:
        print(f"    scikit-learn, default threads    {t_def:8.2f} s wall {c_def:8.2f} s CPU   ({t_def / n:.3f} s a fit)")
    print(f"    batched                          {t_new:8.2f} s wall {c_new:8.2f} s CPU   ({t_new / n:.3f} s a fit)")
    print(f"    ratio old / new (wall): {t_one / t_new:.1f}x with 1 BLAS thread"
          + (f", {t_def / t_new:.1f}x with default threads" if t_def is not None else ""))
    print(f"    batched optimum minus scikit-learn's (LML + log prior), worst fit: {gap:+.2e}; hyperparameters "
          f"max |log ratio| {np.max(np.abs(np.log(new.length_scale / ref.length_scale))):.2e} (length scale)")
    return {"route": f"GP fits, {n} at once against one at a time (scikit-learn, 1 BLAS thread)",
            "previous_s": t_one, "current_s": t_new, "previous_cpu_s": c_one, "current_cpu_s": c_new}


if __name__ == "__main__":
    main(sys.argv[1:])
