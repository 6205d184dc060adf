"""Confidence intervals the report computes itself: over realizations of one track.

The population CIs (over tracks and targets) come from ``summary.json``; the single-track
experiments (the σ sweep, the randomized detail of the first track) only vary the localization
noise, so their CIs resample realizations: a percentile bootstrap, seeded, vectorized.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics.labels import ordered_methods
from pipeline.evaluation.metrics.spec import compute, matrices, percentile
from reports.shared.numbers import Estimate

BOOTSTRAP = 1000
CI_LEVEL = 0.95


def bootstrap_track(mats: dict[str, np.ndarray], n_boot: int = BOOTSTRAP, seed: int = 0) -> dict[str, Estimate]:
    """Each metric of ``pipeline.evaluation.metrics.spec.METRICS`` with a percentile-bootstrap CI over
    realizations (rows of the (R, K) matrices, see ``metrics.matrices``)."""
    R = next(iter(mats.values())).shape[0]
    point = compute(mats)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, R, size=(n_boot, R))
    boot = compute({k: v[idx] for k, v in mats.items()})
    a = 100 * (1 - CI_LEVEL) / 2
    out = {}
    for k in point:  # the metrics whose columns the table has
        lo, hi = (float(x) for x in percentile(boot[k], [a, 100 - a], axis=-1))
        out[k] = Estimate(float(point[k]), lo, hi)
    return out


def track_summary(df: pd.DataFrame, *, n_boot: int = BOOTSTRAP, seed: int = 0, by: str = "setting") -> dict:
    """{setting: {"sigma_m", "n_realizations", "methods": {method: {metric: Estimate}}}}, groups of
    ``by`` in order of first appearance; the seed is the same for every cell so reruns agree."""
    out: dict = {}
    for setting in dict.fromkeys(df[by]):
        g = df[df[by] == setting]
        sigma = float(g["sigma_m"].iloc[0]) if "sigma_m" in g else float("nan")
        cell = {"sigma_m": sigma, "n_realizations": int(g["realization"].nunique()), "methods": {}}
        for m in ordered_methods(g["method"].unique()):
            cell["methods"][m] = bootstrap_track(matrices(g[g["method"] == m]), n_boot, seed)
        out[setting] = cell
    return out
