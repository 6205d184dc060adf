"""Weak hyperpriors for the GP fits: maximum a posteriori instead of maximum marginal likelihood.

Why: with one score per training view, a component that jumps between neighbouring views (an
oblique view where the classifier wavers between two texture families) leaves the marginal
likelihood on a ridge: a length scale at the views' own spacing, or below it, explains the jumps
as well as noise does, and the optimum runs into the length-scale or noise bound. Neither end is
identifiable from the data. An inverse-gamma prior on each of the two (``1 - 2 * TAIL`` of its
mass between a lower and an upper value) keeps the fit where the data can say something and
barely moves a well-determined fit.

- length scale: between the smallest spacing of the class's training inputs (3 degrees of
  turntable = 0.052 on the unit circle) and the largest distance between them (the circle's
  diameter, 2): shorter scales are below what the views resolve, longer ones are a constant.
- noise variance: between ``noise_prior[0]`` and ``noise_prior[1]`` (config ``models.noise_prior``).

Both act on the log hyperparameters that scikit-learn optimises (``kernel.theta``). The fit is
still scikit-learn's ``GaussianProcessRegressor``; only its ``optimizer`` callable adds the log
prior to the log marginal likelihood, so predictions are scikit-learn's for the fitted kernel.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

TAIL = 0.01  # prior mass below the lower and above the upper value


def inverse_gamma_for(lo: float, hi: float, tail: float = TAIL) -> tuple[float, float]:
    """Shape and scale (alpha, beta) of the inverse-gamma law with ``tail`` of its mass below
    ``lo`` and ``tail`` above ``hi``."""
    from scipy import optimize, special

    if not (0 < lo < hi and np.isfinite(hi)):
        raise ValueError(f"inverse_gamma_for: need 0 < lo < hi, got lo={lo}, hi={hi}")
    if not 0 < tail < 0.5:
        raise ValueError(f"inverse_gamma_for: tail must be in (0, 0.5), got {tail}")

    # P(X < x) = Q(alpha, beta / x) for X ~ InvGamma(alpha, beta). For a given alpha the lower
    # tail fixes beta; the upper tail's mass then falls monotonically in alpha: one root in log alpha.
    def beta_of(a):
        return lo * special.gammainccinv(a, tail)

    def upper_gap(log_a):
        a = np.exp(log_a)
        return special.gammainc(a, beta_of(a) / hi) - tail

    try:
        log_a = optimize.brentq(upper_gap, np.log(1e-3), np.log(1e4), xtol=1e-12)
    except ValueError:
        raise ValueError(f"inverse_gamma_for: no inverse-gamma law with {tail:g} below {lo:g} and above {hi:g}") from None
    a = float(np.exp(log_a))
    return a, float(beta_of(a))


@dataclass(frozen=True)
class LogInverseGamma:
    """log density of t = log x for x ~ InvGamma(alpha, beta), up to a constant, and its slope."""
    alpha: float
    beta: float
    lo: float
    hi: float

    @classmethod
    def between(cls, lo: float, hi: float) -> "LogInverseGamma":
        return cls(*inverse_gamma_for(lo, hi), lo=float(lo), hi=float(hi))

    def __call__(self, t: float) -> tuple[float, float]:
        e = self.beta * np.exp(-t)
        return -self.alpha * t - e, -self.alpha + e

    def describe(self) -> dict:
        return {"law": "inverse_gamma", "alpha": self.alpha, "beta": self.beta,
                "mass_below_lo": TAIL, "lo": self.lo, "mass_above_hi": TAIL, "hi": self.hi}


@dataclass(frozen=True)
class LogitBeta:
    """The instance term's variance split (``models.instance_prior = "split"``): r = b / (a + b) ~
    Beta(alpha, beta), as a density of u = logit r = log b - log a (the Jacobian r(1 - r) included,
    so the law is proper in u), up to a constant, and its slope in u. Why: with no prior the joint
    fit runs b to either bound (r -> 0: no instance term; r -> 1: no viewpoint curve), ends the data
    of a few training instances cannot tell apart from the middle."""
    alpha: float
    beta: float

    def __call__(self, u):
        from scipy.special import expit

        # log r = -log(1 + e^-u), log(1 - r) = -log(1 + e^u), both without overflow
        lp = -self.alpha * np.logaddexp(0.0, -u) - self.beta * np.logaddexp(0.0, u)
        r = expit(u)
        return lp, self.alpha * (1.0 - r) - self.beta * r

    def describe(self) -> dict:
        return {"law": "beta", "of": "instance_amplitude / (amplitude + instance_amplitude)",
                "alpha": self.alpha, "beta": self.beta}


def input_range(X: np.ndarray) -> tuple[float, float]:
    """Smallest non-zero and largest distance between training inputs (N, d)."""
    X = np.asarray(X, float)
    d = np.sqrt(np.maximum(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1), 0.0))
    pos = d[d > 1e-12]
    if pos.size == 0:
        raise ValueError("input_range: the training inputs are all the same point")
    return float(pos.min()), float(pos.max())


def map_optimizer(priors: dict[int, LogInverseGamma]) -> Callable:
    """A scikit-learn ``optimizer`` callable: L-BFGS-B on -(log marginal likelihood + log prior),
    where ``priors`` maps an index of ``kernel.theta`` to its prior."""
    from scipy import optimize

    def objective(obj_func, theta):
        value, grad = obj_func(theta, eval_gradient=True)   # -LML and its gradient
        grad = np.array(grad, dtype=float)
        for i, prior in priors.items():
            lp, dlp = prior(theta[i])
            value -= lp
            grad[i] -= dlp
        return value, grad

    def optimizer(obj_func, initial_theta, bounds):
        res = optimize.minimize(lambda th: objective(obj_func, th), initial_theta, method="L-BFGS-B",
                                jac=True, bounds=bounds)
        if not res.success:  # the same warning scikit-learn's own optimizer gives, so diagnostics list it
            from sklearn.exceptions import ConvergenceWarning
            warnings.warn(f"lbfgs failed to converge (MAP fit): {res.message}", ConvergenceWarning)
        return res.x, res.fun

    return optimizer


def log_prior(priors: dict[int, LogInverseGamma], theta: np.ndarray) -> float:
    return float(sum(p(theta[i])[0] for i, p in priors.items()))
