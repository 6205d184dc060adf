"""The heavy-tailed measurement model of the ``*_t`` fusion methods: a Student-t around the GP
predictive, and its degrees of freedom ν fitted on standardized residuals.

Per step and score component the Gaussian methods use N(s; m, v): the conditional predictive of
the step given the past (With Uncertainty: the paper's closed form over the past dropout samples;
Model Based: the chain rule). The ``*_t`` variants use t_ν(s; m, v), location m and squared scale v
(so the Gaussian is the limit ν → ∞): one far crop costs its class log(1 + e²/(ν v)) · (ν + 1)/2
instead of e²/(2v), so a component whose model fails on a view does not veto the class alone.
ν is one number per cross-fitting fold, shared by every class and component (so the constant
below cancels in the normalisation; it is kept for the literal densities), fitted by maximum
likelihood on the standardized residuals of the other folds' labelled crops
(``pipeline.evaluation.domain.tails``).
"""
from __future__ import annotations

import math

import numpy as np

# ν is searched in [NU_MIN, NU_MAX]: 1 is the Cauchy; at 1000 the t is the Gaussian to < 1e-3 in
# its central 99.9 %, so a fit at the upper bound says "no heavier tail than the Gaussian".
NU_MIN, NU_MAX = 1.0, 1000.0


def log_const(nu: float) -> float:
    """log t_ν's normalising constant at unit scale, relative to the Gaussian's -log(2π)/2 that the
    engine leaves out: lgamma((ν+1)/2) - lgamma(ν/2) - log(ν π)/2 + log(2π)/2."""
    return (math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu) - 0.5 * math.log(nu * math.pi)
            + 0.5 * math.log(2.0 * math.pi))


def logpdf(z, nu: float) -> np.ndarray:
    """log t_ν(z) at unit scale (the full density)."""
    z = np.asarray(z, float)
    return log_const(nu) - 0.5 * math.log(2.0 * math.pi) - 0.5 * (nu + 1.0) * np.log1p(z * z / nu)


def fit_df(z) -> float | None:
    """Maximum-likelihood ν of unit-scale t on standardized residuals ``z`` (the scale is the
    model's, not refitted: ν alone absorbs the excess tail); None for no finite residual. A
    log-spaced grid finds the basin, bounded Brent on log ν refines it."""
    from scipy.optimize import minimize_scalar

    z = np.asarray(z, float).ravel()
    z = z[np.isfinite(z)]
    if not len(z):
        return None
    z2 = z * z

    def nll(u: float) -> float:
        nu = math.exp(u)
        return -float(len(z2) * log_const(nu) - 0.5 * (nu + 1.0) * np.sum(np.log1p(z2 / nu)))

    grid = np.linspace(math.log(NU_MIN), math.log(NU_MAX), 41)
    vals = [nll(u) for u in grid]
    i = int(np.argmin(vals))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    res = minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    u = float(res.x) if res.fun <= vals[i] else float(grid[i])
    return float(min(max(math.exp(u), NU_MIN), NU_MAX))


def gaussian_equivalent(z, nu: np.ndarray | float) -> np.ndarray:
    """Φ⁻¹(T_ν(z)): the residual's place in its t predictive on the Gaussian scale, so that the
    domain-fit summary (PIT, |z| quantiles, 95 % coverage) reads a t likelihood as it reads a
    Gaussian one (``pipeline.evaluation.domain.fit``)."""
    from scipy.special import ndtri, stdtr

    z = np.asarray(z, float)
    nu = np.broadcast_to(np.asarray(nu, float), z.shape)
    # upper tail by symmetry, so that a far residual keeps its digits (1 - T near 1 rounds to 0)
    tail = stdtr(nu, -np.abs(z))
    return np.sign(z) * -ndtri(tail)
