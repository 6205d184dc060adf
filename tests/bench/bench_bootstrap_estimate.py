"""How far the bootstrap's up-front time estimate (``resampler.draw_seconds``: a small draw timed
and scaled linearly) lies from the time the draws take, on this machine at its present load.

Prints est / real for two target structures at 100,000 draws; the estimate is read as good within
a factor of 4 either way (a timing, so it lives here and not in the tests).

    python tests/bench/bench_bootstrap_estimate.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.evaluation.statistics.resampler import Resampler, draw_seconds

STRUCTURES = {"12 targets x 4": [[4] * 12], "6 unequal targets": [[1, 3, 4, 2, 4, 4]]}


def main(n: int = 100_000) -> dict:
    out = {}
    for name, structure in STRUCTURES.items():
        est = min(draw_seconds(structure, n) for _ in range(2))
        t0 = time.perf_counter()
        r = Resampler(structure, n, [1])
        r.draws(np.random.default_rng(1).random(r.shape), "mean")
        real = time.perf_counter() - t0
        ok = real / 4 < est < real * 4
        print(f"bootstrap estimate, {name}, {n} draws: estimated {est:.3g} s, took {real:.3g} s, "
              f"ratio {est / real:.2f} ({'within' if ok else 'OUTSIDE'} a factor of 4)")
        out[name] = {"estimate_s": est, "real_s": real}
    return out


if __name__ == "__main__":
    main()
