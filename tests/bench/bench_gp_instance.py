"""The instance term's fits (``models.instance_term``): one scipy L-BFGS-B at a time (the previous
route) against every fit at once (``pipeline/method/gp_instance_batch.py``), on the same fits in
one run (printed, never asserted).

The fits are an ETH-80 category bank's shape (configs/real_category.toml, scaled by the
arguments): ``--classes`` classes of ``--instances`` turntable instances at the same
``--azimuths`` azimuths (``--unbalanced``: each instance its own azimuths, the dense evaluation),
``--components`` components, the config's bounds, hyperpriors and restarts; views and targets are
the tests' generated hierarchical classes (random hyperparameters). Both routes share the plain fit (batched, timed
apart); the per-fit route runs with one BLAS thread (its default threads spin on a loaded
machine). Prints the load, wall and CPU seconds of each route, the ratio and the worst optimum gap
(batched minus per-fit, LML + log prior; should be >= -1e-6).

    python tests/bench/bench_gp_instance.py --classes 6 --components 14 --instances 8
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.method.gp_instance_fit import fit_instance_models  # noqa: E402
from tests.bench.bench_gp import timed  # noqa: E402
from tests.pipeline.method.test_gp_instance_batch import hierarchical_class  # noqa: E402


def workload(classes: int, components: int, instances: int, azimuths: int, unbalanced: bool, seed: int = 0):
    rng = np.random.default_rng(seed)
    return tuple(map(list, zip(*(hierarchical_class(rng, instances, azimuths, components, balanced=not unbalanced)
                                 for _ in range(classes)))))


def main(argv=None) -> None:
    from threadpoolctl import threadpool_limits

    from pipeline.method.gp_fit import fit_class_models

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--classes", type=int, default=4)
    ap.add_argument("--components", type=int, default=14)
    ap.add_argument("--instances", type=int, default=8)
    ap.add_argument("--azimuths", type=int, default=16)
    ap.add_argument("--unbalanced", action="store_true", help="each instance at its own azimuths (dense evaluation)")
    ap.add_argument("--skip-per-fit", action="store_true", help="time the batched route only (a whole bank)")
    a = ap.parse_args(argv if argv is not None else [])
    Xs, Ys, labs = workload(a.classes, a.components, a.instances, a.azimuths, a.unbalanced)
    kw = dict(classes=[f"c{i}" for i in range(a.classes)], components=list(range(a.components)), progress=False)
    for r in ("batch", "per_fit"):   # imports and first-call costs out of the timing
        fit_instance_models(Xs[:1], [Ys[0][:1]], labs[:1], kw["classes"][:1], [0], restarts=0, instance_route=r,
                            progress=False)
    load0 = os.getloadavg()
    _, t_plain, c_plain = timed(lambda: fit_class_models(Xs, Ys, **kw))
    (_, dnew), t_new, c_new = timed(lambda: fit_instance_models(Xs, Ys, labs, instance_route="batch", **kw))
    t_old = c_old = None
    if not a.skip_per_fit:
        with threadpool_limits(1, user_api="blas"):
            (_, dref), t_old, c_old = timed(lambda: fit_instance_models(Xs, Ys, labs, instance_route="per_fit", **kw))
    load1 = os.getloadavg()
    n = a.classes * a.components
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{load0[0]:.2f} before, {load1[0]:.2f} after")
    print(f"{n} instance-term fits ({a.classes} classes x {a.components} components, {a.instances} instances x "
          f"{a.azimuths} azimuths{', unbalanced' if a.unbalanced else ''}, {dnew[0]['restarts']} restarts)")
    print(f"    plain fit alone (batched, in both)  {t_plain:8.2f} s wall {c_plain:8.2f} s CPU")
    if t_old is not None:
        print(f"    per fit, 1 BLAS thread, + plain     {t_old:8.2f} s wall {c_old:8.2f} s CPU   ({t_old / n:.3f} s a fit)")
    print(f"    batched, + plain                    {t_new:8.2f} s wall {c_new:8.2f} s CPU   ({t_new / n:.3f} s a fit)")
    if t_old is not None:
        gap = min((b["log_marginal_likelihood"] + (b["log_prior"] or 0)) - (r["log_marginal_likelihood"] + (r["log_prior"] or 0))
                  for b, r in zip(dnew, dref))
        print(f"    ratio old / new: {t_old / t_new:.1f}x wall, {c_old / c_new:.1f}x CPU; instance part alone "
              f"{(c_old - c_plain) / max(c_new - c_plain, 1e-9):.1f}x CPU")
        print(f"    batched optimum minus per-fit (LML + log prior), worst fit: {gap:+.2e}")


if __name__ == "__main__":
    main(sys.argv[1:])
