"""Confidence intervals the report computes itself: over realizations of one track.

The population CIs (over tracks and targets) come from ``summary.json``; the single-track
experiments (the σ sweep, the randomized detail of the first track) only vary the localization
noise, so their CIs resample realizations: a percentile bootstrap, seeded, vectorized.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.labels import ordered_methods
from reports.numbers import Estimate

BOOTSTRAP = 1000
CI_LEVEL = 0.95
# Metrics per (setting, method) over R realizations × K steps; MGR as log10.
TRACK_METRICS = ("correct_final", "correct_overall", "prob_truth_final", "msde_final",
                 "log10_mgr75_final", "log10_mgr95_final", "log10_mgr75_overall", "log10_mgr95_overall")


def percentile_rows(x: np.ndarray, q: float) -> np.ndarray:
    """Percentile along the last axis that treats +inf as a value (a truth probability of 0)."""
    big = np.finfo(float).max / 4
    out = np.percentile(np.where(np.isposinf(x), big, x), q, axis=-1)
    # Interpolating toward a stand-in lands anywhere above any real log10 MGR: that is +inf.
    return np.where(out > 1e300, np.inf, out)


def _stats(mats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every metric of (..., R, K) matrices, reduced over R (and K): arrays of shape (...)."""
    c, p, s, g = mats["correct"], mats["p_truth"], mats["msde"], mats["log10_mgr"]
    lead = g.shape[:-2]
    return {
        "correct_final": c[..., -1].mean(-1), "correct_overall": c.mean((-2, -1)),
        "prob_truth_final": p[..., -1].mean(-1), "msde_final": s[..., -1].mean(-1),
        "log10_mgr75_final": percentile_rows(g[..., -1], 75),
        "log10_mgr95_final": percentile_rows(g[..., -1], 95),
        "log10_mgr75_overall": percentile_rows(g.reshape(*lead, -1), 75),
        "log10_mgr95_overall": percentile_rows(g.reshape(*lead, -1), 95),
    }


def matrices(df: pd.DataFrame) -> dict[str, np.ndarray]:
    """(R, K) matrices of one (setting, method)'s rows, realizations × steps (NaN where absent)."""
    r_codes, r_vals = pd.factorize(df["realization"], sort=True)
    k_codes, k_vals = pd.factorize(df["step"], sort=True)
    out = {}
    for col in ("correct", "p_truth", "msde", "log10_mgr"):
        m = np.full((len(r_vals), len(k_vals)), np.nan)
        m[r_codes, k_codes] = df[col].to_numpy(float)
        out[col] = m
    return out


def bootstrap_track(mats: dict[str, np.ndarray], n_boot: int = BOOTSTRAP, seed: int = 0) -> dict[str, Estimate]:
    """Each metric with a percentile-bootstrap CI over realizations (rows of the matrices)."""
    R = next(iter(mats.values())).shape[0]
    point = _stats(mats)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, R, size=(n_boot, R))
    boot = _stats({k: v[idx] for k, v in mats.items()})
    a = 100 * (1 - CI_LEVEL) / 2
    out = {}
    for k in TRACK_METRICS:
        lo, hi = (float(x) for x in percentile_rows(boot[k], [a, 100 - a]))
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
