"""Fitting the per-class GP models (docs/design.md §5): one GP ``C*RBF + White`` per (class,
component), by marginal likelihood or, with ``hyperprior = "inverse_gamma"``, by marginal
likelihood times the weak priors of ``pipeline/method/gp_prior.py``. Two routes to the same
objective, starts and optimizer: ``route = "batch"`` (default) fits every GP at once
(``pipeline/method/gp_batch.py``); ``route = "sklearn"`` fits one ``GaussianProcessRegressor`` at
a time, the reference the tests and ``tests/bench/bench_gp.py`` compare against. Returns a
``pipeline.method.gp.GPClassModels`` and per-fit diagnostics.
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from pipeline.infra import seeds
from pipeline.infra.config import ModelsConfig, bounds_problem
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_prior import LogInverseGamma, input_range, log_prior, map_optimizer
from pipeline.method.gp_batch import Problem, fit_problems, prior_rows, starts_for
from pipeline.infra.progress import bar as progress_bar


# The defaults are the config's ([models] in pipeline/infra/config/learning.py): one source.
_DEFAULTS = ModelsConfig()
ROUTES = ("batch", "sklearn")
HYPERPARAMETERS = ("amplitude", "length_scale", "noise")   # kernel.theta order (checked: theta_index)


@functools.cache
def theta_index(name: str) -> int:
    """Position of a hyperparameter in ``kernel.theta`` of the kernel every fit uses."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    return [h.name for h in (ConstantKernel() * RBF() + WhiteKernel()).hyperparameters].index(name)


@dataclass
class FitSpec:
    """One (class, component) fit: inputs, targets, their mean, the bounds (raw units), the
    priors ({theta index: law}), the starting point and the restarts' random state."""
    c: int
    f: int
    X: np.ndarray
    y: np.ndarray
    mean: float
    bounds: dict
    priors: dict
    init: dict
    random_state: int

    def kernel(self, values: dict | None = None):
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

        v = self.init if values is None else values
        return (ConstantKernel(v["amplitude"], self.bounds["amplitude"]) * RBF(v["length_scale"], self.bounds["length_scale"])
                + WhiteKernel(v["noise"], self.bounds["noise"]))


def _caught(caught) -> list[str]:
    from sklearn.exceptions import ConvergenceWarning

    return sorted({f"{w.category.__name__}: {w.message}" for w in caught
                   if issubclass(w.category, (ConvergenceWarning, UserWarning, RuntimeWarning))})


def fit_sklearn(s: FitSpec, restarts: int) -> tuple[np.ndarray, float, float | None, list[str], dict]:
    """The reference route: scikit-learn's ``GaussianProcessRegressor`` fit of one spec.
    Returns (theta, LML, log prior, warnings, optimizer record)."""
    from sklearn.gaussian_process import GaussianProcessRegressor

    gpr = GaussianProcessRegressor(s.kernel(), alpha=0.0, normalize_y=False,
                                   optimizer=map_optimizer(s.priors) if s.priors else "fmin_l_bfgs_b",
                                   n_restarts_optimizer=restarts, random_state=s.random_state)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gpr.fit(s.X, s.y - s.mean)
    theta = np.array(gpr.kernel_.theta, float)
    # With priors, scikit-learn's stored value is the optimised objective (LML + log prior).
    lml = float(gpr.log_marginal_likelihood(theta)) if s.priors else float(gpr.log_marginal_likelihood_value_)
    return theta, lml, log_prior(s.priors, theta) if s.priors else None, _caught(caught), {"route": "sklearn"}


def fit_batched(specs: list[FitSpec], restarts: int, prior_index: tuple[int, int], cache: dict | None = None
                ) -> list[tuple[np.ndarray, float, float | None, list[str], dict]]:
    """Every spec at once (``pipeline.method.gp_batch.fit_problems``); the same per-fit results
    and warnings as ``fit_sklearn``: an L-BFGS-B run that did not converge warns as scikit-learn's
    fit does, and the chosen hyperparameters are checked against the bounds by scikit-learn's
    kernel."""
    from scipy.optimize import OptimizeResult
    from sklearn.exceptions import ConvergenceWarning

    if tuple(theta_index(n) for n in ("k1__k1__constant_value", "k1__k2__length_scale", "k2__noise_level")) != (0, 1, 2):
        raise RuntimeError("fit_batched: scikit-learn's kernel.theta order is not (amplitude, length scale, noise)")
    problems = []
    for s in specs:
        lb = np.log(np.array([s.bounds[n] for n in HYPERPARAMETERS], float))
        theta0 = np.log([s.init[n] for n in HYPERPARAMETERS])
        problems.append(Problem(s.X, s.y - s.mean, lb, prior_rows(s.priors, *prior_index),
                                starts_for(theta0, lb, restarts, s.random_state)))
    out = []
    for s, p, r in zip(specs, problems, fit_problems(problems, cache=cache)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for run in r.runs:
                if run["status"] == 0:
                    continue
                if s.priors:   # the text gp_prior.map_optimizer warns with
                    warnings.warn(f"lbfgs failed to converge (MAP fit): {run['message']}", ConvergenceWarning)
                else:
                    _lbfgs_warning(OptimizeResult(status=run["status"], nit=run["nit"], message=run["message"]))
            k = s.kernel()
            k.theta = r.theta
            k._check_bounds_params()
        record = {"route": "batch", "fit_key": p.key, "objective": r.objective,
                  "runs": [{"status": x["status"], "nit": x["nit"], "nfev": x["nfev"]} for x in r.runs]}
        out.append((r.theta, r.lml, r.log_prior if s.priors else None, _caught(caught), record))
    return out


def _lbfgs_warning(res) -> None:
    """The warning scikit-learn's own optimizer gives for an L-BFGS-B run that did not converge
    (its helper where this scikit-learn has it, else the same first line)."""
    from sklearn.exceptions import ConvergenceWarning

    try:
        from sklearn.utils.optimize import _check_optimize_result
    except ImportError:
        warnings.warn(f"lbfgs failed to converge after {res.nit} iteration(s) (status={res.status}):\n{res.message}\n",
                      ConvergenceWarning)
        return
    _check_optimize_result("lbfgs", res)


def _progress(items, enabled: bool):
    bar = progress_bar(total=len(items), desc="GP fits", unit="fit", enabled=enabled)
    for it in items:
        yield it
        bar.update(1)
    bar.close()


def fit_class_models(X_by_class: Sequence[np.ndarray], Y_by_class: Sequence[np.ndarray],
                     classes: Sequence[str], components: Sequence[int], *, restarts: int = _DEFAULTS.restarts,
                     amplitude_bounds: tuple[float, float] = _DEFAULTS.amplitude_bounds,
                     length_scale_bounds: tuple[float, float] = _DEFAULTS.length_scale_bounds,
                     noise_bounds: tuple[float, float] = _DEFAULTS.noise_bounds, seed: int = _DEFAULTS.seed,
                     component_names: Sequence[str] | None = None, progress: bool = True,
                     noise_floor: np.ndarray | None = None, hyperprior: str = _DEFAULTS.hyperprior,
                     noise_prior: tuple[float, float] = _DEFAULTS.noise_prior, route: str = "batch",
                     cache: dict | None = None) -> tuple[GPClassModels, list[dict[str, Any]]]:
    """Fit one GP per (class, component) by marginal likelihood (or, with
    ``hyperprior = "inverse_gamma"``, by marginal likelihood times weak priors on the length scale
    and the noise variance: ``pipeline/method/gp_prior.py``).

    ``X_by_class[c]`` (N_c, d) inputs, ``Y_by_class[c]`` (F, N_c) targets. Constant mean = the
    training mean; kernel ``ConstantKernel * RBF + WhiteKernel`` within the given bounds;
    ``restarts`` extra L-BFGS-B starts drawn log-uniformly in the bounds, seeded per fit from
    ``seed``. Returns the models and one diagnostics dict per fit (hyperparameters, log marginal
    likelihood, the optimizer's warnings, which hyperparameters ended at a bound, the training
    scores' std over the views; ``optimizer``: the route, and for the batched one each start's
    L-BFGS-B status and iterations). ``noise_floor`` (C, F), when given, replaces the lower noise bound
    of each fit (a data-driven floor; values at or above the upper bound are an error).
    ``noise_prior`` (low, high): the noise variance's prior holds 98 % of its mass in between.
    ``route``: "batch" (every fit at once) or "sklearn" (the reference, one at a time).
    ``cache`` ({fit key: result}, batch route): fits already made with the same data, settings and
    starts are reused (the banks of one models stage run share it).
    """
    C, F = len(classes), len(components)
    if len(X_by_class) != C or len(Y_by_class) != C:
        raise ValueError(f"fit_class_models: {C} classes but {len(X_by_class)} input and {len(Y_by_class)} target sets")
    for name, b in (("amplitude_bounds", amplitude_bounds), ("length_scale_bounds", length_scale_bounds),
                    ("noise_bounds", noise_bounds), ("noise_prior", noise_prior)):
        problem = bounds_problem(b)
        if problem is not None:
            raise ValueError(f"fit_class_models: {name} {problem}")
    if noise_floor is not None:
        noise_floor = np.asarray(noise_floor, dtype=float)
        if noise_floor.shape != (C, F) or not np.all(np.isfinite(noise_floor)) or np.any(noise_floor <= 0):
            raise ValueError(f"fit_class_models: noise_floor must be ({C}, {F}) positive finite values")
        if np.any(noise_floor >= noise_bounds[1]):
            raise ValueError(f"fit_class_models: a noise floor reaches the upper noise bound {noise_bounds[1]}")
    if hyperprior not in ("none", "inverse_gamma"):
        raise ValueError(f"fit_class_models: hyperprior must be 'none' or 'inverse_gamma', got {hyperprior!r}")
    noise_law = LogInverseGamma.between(*noise_prior) if hyperprior != "none" else None
    i_ell, i_noise = theta_index("k1__k2__length_scale"), theta_index("k2__noise_level")
    if route not in ROUTES:
        raise ValueError(f"fit_class_models: route must be one of {ROUTES}, got {route!r}")
    specs = []
    for c in range(C):
        X = np.asarray(X_by_class[c], dtype=float)
        Y = np.asarray(Y_by_class[c], dtype=float)
        if X.ndim != 2 or len(X) < 2:
            raise ValueError(f"fit_class_models: class {classes[c]!r} needs (N >= 2, d) inputs, got {X.shape}")
        if Y.shape != (F, len(X)):
            raise ValueError(f"fit_class_models: class {classes[c]!r} targets must be ({F}, {len(X)}), got {Y.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise ValueError(f"fit_class_models: class {classes[c]!r} has non-finite inputs or targets")
        priors = {} if noise_law is None else {i_ell: LogInverseGamma.between(*input_range(X)), i_noise: noise_law}
        for f in range(F):
            y = Y[f]
            m = float(y.mean())
            nb = noise_bounds if noise_floor is None else (float(noise_floor[c, f]), noise_bounds[1])
            # Starting point: the data's own scale, clipped into the bounds.
            v = float(y.var())
            init = {"amplitude": float(np.clip(v if v > 0 else amplitude_bounds[0], *amplitude_bounds)),
                    "length_scale": float(np.clip(1.0, *length_scale_bounds)),
                    "noise": float(np.clip(0.1 * v if v > 0 else nb[0], *nb))}
            specs.append(FitSpec(c, f, X, y, m, {"amplitude": tuple(amplitude_bounds),
                                                 "length_scale": tuple(length_scale_bounds), "noise": tuple(nb)},
                                 priors, init, seeds.integer(seed, int(c), int(f))))
    if route == "sklearn":
        fitted = [fit_sklearn(s, restarts) for s in _progress(specs, progress)]
    else:
        fitted = fit_batched(specs, restarts, (i_ell, i_noise), cache)
    mean, amp, ell, noise = (np.zeros((C, F)) for _ in range(4))
    diags: list[dict[str, Any]] = []
    for s, (theta, lml, lp, msgs, opt) in zip(specs, fitted):
        c, f = s.c, s.f
        mean[c, f] = s.mean
        amp[c, f], ell[c, f], noise[c, f] = np.exp(theta)
        fitted_values = {"amplitude": amp[c, f], "length_scale": ell[c, f], "noise": noise[c, f]}
        at_bound = [f"{n} at {'lower' if abs(np.log(val / s.bounds[n][0])) < 0.01 else 'upper'} bound"
                    for n, val in fitted_values.items()
                    if min(abs(np.log(val / s.bounds[n][0])), abs(np.log(val / s.bounds[n][1]))) < 0.01]
        diags.append({
            "class": str(classes[c]), "component": int(components[f]),
            "component_name": None if component_names is None else str(component_names[f]),
            "n_train": int(len(s.X)), "mean": s.mean, "train_std": float(s.y.std()),
            "noise_bounds": [float(s.bounds["noise"][0]), float(s.bounds["noise"][1])],
            **{n: float(val) for n, val in fitted_values.items()},
            # With priors the optimised objective is LML + log prior: the marginal likelihood
            # itself and the prior are reported separately.
            "log_marginal_likelihood": lml,
            "log_prior": lp if s.priors else None,
            "hyperprior": ({"length_scale": s.priors[i_ell].describe(), "noise": s.priors[i_noise].describe()}
                           if s.priors else None),
            "init": dict(s.init),
            "restarts": int(restarts), "random_state": s.random_state,
            "at_bound": at_bound, "warnings": msgs, "optimizer": opt,
        })
    models = GPClassModels(classes, components, [np.asarray(x, float) for x in X_by_class],
                           [np.asarray(y, float) for y in Y_by_class], mean, amp, ell, noise,
                           component_names=component_names)
    return models, diags
