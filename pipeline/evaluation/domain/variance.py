"""The calibrated likelihood: an additive test-domain variance per score component, cross-fitted.

The GPs are fitted on turntable views; on room crops their residuals are far wider than their
predictive variance (``pipeline.evaluation.domain.fit``). The calibrated likelihood adds one
variance δ²_f per score component f to the noise of every test measurement of every class
(``GPClassModels.with_test_variance``). δ²_f maximises the Gaussian likelihood of the residuals
r = mean score - μ of labelled crops (each crop under its own class's GP, variance v = the GP
predictive variance):

    δ²_f = argmax_{δ² >= 0}  Σ_i -½ [ln(v_i + δ²) + r_i² / (v_i + δ²)]

Per component and not per (class, component): with a single scan, the crops that may be used for
a target exclude the target's own, so a per-class δ² of the target's own class could not be
estimated at all. Cross-fitting (``fold_keys``): with two or more scans, cells of scan s use the
δ² estimated on the crops of the other scans; with one scan, the cells of target t use the δ²
estimated on the other instances' crops. Either way no evaluated cell's labels (instance identity
and pose) enter the variance it is evaluated with.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

MODES = ("none", "cross_fit")


def neg_log_lik(delta: np.ndarray, r2: np.ndarray, v: np.ndarray) -> np.ndarray:
    """-Σ log N(r; 0, v + δ²) up to the constant, for every δ² of ``delta`` (D,) -> (D,)."""
    s = v[None, :] + np.asarray(delta, float)[:, None]
    return 0.5 * np.sum(np.log(s) + r2[None, :] / s, axis=1)


def ml_variance(resid, var) -> float:
    """Maximum-likelihood additive variance δ² >= 0 of residuals ``resid`` with known variances ``var``.

    A log-spaced grid over [1e-12, 10 max r²] finds the basin (the likelihood need not be concave
    in δ²), bounded Brent refines it, and δ² = 0 wins when it is at least as likely.
    """
    r = np.asarray(resid, float).ravel()
    v = np.asarray(var, float).ravel()
    ok = np.isfinite(r) & np.isfinite(v) & (v > 0)
    r, v = r[ok], v[ok]
    if not len(r):
        return 0.0
    r2 = r * r
    hi = max(float(r2.max()) * 10.0, 1e-10)
    grid = np.concatenate([[0.0], np.geomspace(1e-12, hi, 121)])
    nll = neg_log_lik(grid, r2, v)
    i = int(np.argmin(nll))
    if i == 0:
        return 0.0
    lo_u = np.log(grid[i - 1]) if i > 1 else np.log(1e-13)
    hi_u = np.log(grid[min(i + 1, len(grid) - 1)])
    res = minimize_scalar(lambda u: float(neg_log_lik(np.array([np.exp(u)]), r2, v)[0]),
                          bounds=(lo_u, hi_u), method="bounded", options={"xatol": 1e-6})
    best = float(np.exp(res.x)) if res.fun <= nll[i] else float(grid[i])
    return best if float(neg_log_lik(np.array([best]), r2, v)[0]) < nll[0] else 0.0


def fold_keys(table: pd.DataFrame) -> tuple[str, list[str]]:
    """('scan', scans) with two or more scans, else ('instance', instances)."""
    scans = sorted(set(table["scan"]))
    if len(scans) >= 2:
        return "scan", scans
    return "instance", sorted(set(table["instance"]))


def cross_fit(table: pd.DataFrame, components, by: str | None = None,
              keys=None) -> tuple[str, dict[str, dict[int, float]], dict[str, dict[int, int]]]:
    """δ² per fold and component, each from the rows outside the fold.

    ``table``: ``domain_fit.crop_residuals`` rows (scan, instance, component, obs, mu, var). Returns
    (fold column, {fold: {component: δ²}}, {fold: {component: rows used}}); a component without
    rows outside a fold gets δ² = 0 and 0 rows.
    """
    col, default_keys = fold_keys(table) if by is None else (by, sorted(set(table[by])))
    keys = default_keys if keys is None else list(keys)
    r = table["obs"].to_numpy(float) - table["mu"].to_numpy(float)
    v = table["var"].to_numpy(float)
    comp = table["component"].to_numpy()
    fold = table[col].to_numpy()
    est, used = {}, {}
    for k in keys:
        est[str(k)], used[str(k)] = {}, {}
        out = fold != k
        for f in components:
            m = out & (comp == f)
            est[str(k)][int(f)] = ml_variance(r[m], v[m]) if m.any() else 0.0
            used[str(k)][int(f)] = int(m.sum())
    return col, est, used


def cell_fold(col: str, scan: str, target: str) -> str:
    """The fold whose δ² a cell of (scan, target) uses."""
    return scan if col == "scan" else target


def row_variances(table: pd.DataFrame, col: str, est: dict[str, dict[int, float]]) -> np.ndarray:
    """δ² of every residual row from its own fold's estimate (for the calibrated domain fit: each
    crop standardized with a variance that did not see it)."""
    fold = table[col].astype(str).to_numpy()
    comp = table["component"].to_numpy()
    return np.array([est.get(k, {}).get(int(f), 0.0) for k, f in zip(fold, comp)], float)
