"""Fitting the per-class GP models with scikit-learn (docs/design.md §5): one
``GaussianProcessRegressor(C*RBF + White)`` per (class, component), by marginal likelihood or, with
``hyperprior = "inverse_gamma"``, by marginal likelihood times the weak priors of
``pipeline/method/gp_prior.py``. Returns a ``pipeline.method.gp.GPClassModels`` and per-fit diagnostics.
"""
from __future__ import annotations

import functools
import warnings
from typing import Any, Sequence

import numpy as np

from pipeline.infra.config import ModelsConfig, bounds_problem
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_prior import LogInverseGamma, input_range, log_prior, map_optimizer


# The defaults are the config's ([models] in pipeline/infra/config/learning.py): one source.
_DEFAULTS = ModelsConfig()


@functools.cache
def theta_index(name: str) -> int:
    """Position of a hyperparameter in ``kernel.theta`` of the kernel every fit uses."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    return [h.name for h in (ConstantKernel() * RBF() + WhiteKernel()).hyperparameters].index(name)


def fit_class_models(X_by_class: Sequence[np.ndarray], Y_by_class: Sequence[np.ndarray],
                     classes: Sequence[str], components: Sequence[int], *, restarts: int = _DEFAULTS.restarts,
                     amplitude_bounds: tuple[float, float] = _DEFAULTS.amplitude_bounds,
                     length_scale_bounds: tuple[float, float] = _DEFAULTS.length_scale_bounds,
                     noise_bounds: tuple[float, float] = _DEFAULTS.noise_bounds, seed: int = _DEFAULTS.seed,
                     component_names: Sequence[str] | None = None, progress: bool = True,
                     noise_floor: np.ndarray | None = None, hyperprior: str = _DEFAULTS.hyperprior,
                     noise_prior: tuple[float, float] = _DEFAULTS.noise_prior,
                     ) -> tuple[GPClassModels, list[dict[str, Any]]]:
    """Fit one GP per (class, component) with scikit-learn by marginal likelihood (or, with
    ``hyperprior = "inverse_gamma"``, by marginal likelihood times weak priors on the length scale
    and the noise variance: ``pipeline/method/gp_prior.py``).

    ``X_by_class[c]`` (N_c, d) inputs, ``Y_by_class[c]`` (F, N_c) targets. Constant mean = the
    training mean; kernel ``ConstantKernel * RBF + WhiteKernel`` within the given bounds;
    ``restarts`` extra L-BFGS-B starts drawn log-uniformly in the bounds, seeded per fit from
    ``seed``. Returns the models and one diagnostics dict per fit (hyperparameters, log marginal
    likelihood, the optimizer's warnings, which hyperparameters ended at a bound, the training
    scores' std over the views). ``noise_floor`` (C, F), when given, replaces the lower noise bound
    of each fit (a data-driven floor; values at or above the upper bound are an error).
    ``noise_prior`` (low, high): the noise variance's prior holds 98 % of its mass in between.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    from pipeline.infra.progress import bar as progress_bar

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
    mean, amp, ell, noise = (np.zeros((C, F)) for _ in range(4))
    diags: list[dict[str, Any]] = []
    bar = progress_bar(total=C * F, desc="GP fits", unit="fit", enabled=progress)
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
            a0 = float(np.clip(v if v > 0 else amplitude_bounds[0], *amplitude_bounds))
            l0 = float(np.clip(1.0, *length_scale_bounds))
            n0 = float(np.clip(0.1 * v if v > 0 else nb[0], *nb))
            kernel = (ConstantKernel(a0, tuple(amplitude_bounds)) * RBF(l0, tuple(length_scale_bounds))
                      + WhiteKernel(n0, tuple(nb)))
            rs = int(np.random.SeedSequence([seed, c, f]).generate_state(1)[0])
            gpr = GaussianProcessRegressor(kernel, alpha=0.0, normalize_y=False,
                                           optimizer=map_optimizer(priors) if priors else "fmin_l_bfgs_b",
                                           n_restarts_optimizer=restarts, random_state=rs)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                gpr.fit(X, y - m)
            k = gpr.kernel_
            mean[c, f] = m
            amp[c, f] = k.k1.k1.constant_value
            ell[c, f] = k.k1.k2.length_scale
            noise[c, f] = k.k2.noise_level
            fitted = {"amplitude": amp[c, f], "length_scale": ell[c, f], "noise": noise[c, f]}
            bounds = {"amplitude": amplitude_bounds, "length_scale": length_scale_bounds, "noise": nb}
            at_bound = [f"{n} at {'lower' if abs(np.log(val / bounds[n][0])) < 0.01 else 'upper'} bound"
                        for n, val in fitted.items()
                        if min(abs(np.log(val / bounds[n][0])), abs(np.log(val / bounds[n][1]))) < 0.01]
            msgs = sorted({f"{w.category.__name__}: {w.message}" for w in caught
                           if issubclass(w.category, (ConvergenceWarning, UserWarning, RuntimeWarning))})
            diags.append({
                "class": str(classes[c]), "component": int(components[f]),
                "component_name": None if component_names is None else str(component_names[f]),
                "n_train": int(len(X)), "mean": m, "train_std": float(y.std()),
                "noise_bounds": [float(nb[0]), float(nb[1])],
                **{n: float(val) for n, val in fitted.items()},
                # With priors, scikit-learn's stored value is the optimised objective (LML + log
                # prior): report the marginal likelihood itself and the prior separately.
                "log_marginal_likelihood": float(gpr.log_marginal_likelihood(k.theta)) if priors
                else float(gpr.log_marginal_likelihood_value_),
                "log_prior": log_prior(priors, k.theta) if priors else None,
                "hyperprior": ({"length_scale": priors[i_ell].describe(), "noise": priors[i_noise].describe()}
                               if priors else None),
                "init": {"amplitude": a0, "length_scale": l0, "noise": n0},
                "restarts": int(restarts), "random_state": rs,
                "at_bound": at_bound, "warnings": msgs,
            })
            bar.update(1)
    bar.close()
    models = GPClassModels(classes, components, [np.asarray(x, float) for x in X_by_class],
                           [np.asarray(y, float) for y in Y_by_class], mean, amp, ell, noise,
                           component_names=component_names)
    return models, diags
