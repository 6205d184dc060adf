"""The Student-t likelihood's degrees of freedom, cross-fitted (``evaluate.likelihood_tail``).

Per fold (the calibrated likelihood's folds, ``domain.variance.fold_keys``: the other scans' crops,
or with one scan the other instances'), ν of each heavy-tailed method is the maximum-likelihood
ν of a unit-scale t on the standardized residuals of the labelled crops outside the fold, under
the variance the method's Gaussian uses: the GP predictive (``model_based_t``) or that plus the
view's dropout variance (``with_uncertainty_t``), ``domain.fit.standardized``. One ν per fold,
shared by every class and component. So no evaluated cell's labels enter its own ν.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.method.names import MB_T, WU_T
from pipeline.method.student_t import fit_df, gaussian_equivalent

# the method -> the domain-fit kind whose residuals fit its ν
KINDS = {WU_T: "gp_plus_dropout", MB_T: "gp"}


def cross_fit_df(table: pd.DataFrame, z_by_kind: dict, col: str, keys) -> dict[str, dict[str, float]]:
    """{fold: {method key: ν}} from the rows outside each fold (a fold with none outside: no entry)."""
    fold = table[col].astype(str).to_numpy()
    out: dict[str, dict[str, float]] = {}
    for k in keys:
        outside = fold != str(k)
        nus = {m: fit_df(np.asarray(z_by_kind[kind])[outside]) for m, kind in KINDS.items()}
        nus = {m: v for m, v in nus.items() if v is not None}
        if nus:
            out[str(k)] = nus
    return out


def t_kinds(table: pd.DataFrame, z_by_kind: dict, col: str, est: dict[str, dict[str, float]]) -> dict:
    """{kind + '_t': each row's residual on the Gaussian scale under its own fold's t} (rows of a
    fold without ν are NaN: left out of the summaries), for the domain-fit table."""
    fold = table[col].astype(str).to_numpy()
    out = {}
    for m, kind in KINDS.items():
        nu = np.array([est.get(k, {}).get(m, np.nan) for k in fold], float)
        z = np.asarray(z_by_kind[kind], float)
        g = np.full(len(z), np.nan)
        ok = np.isfinite(nu)
        g[ok] = gaussian_equivalent(z[ok], nu[ok])
        out[f"{kind}_t"] = g
    return out
