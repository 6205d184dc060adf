"""Fitting the class GPs with an instance term (``pipeline/method/gp_instance.py``; docs/design.md §5,
"Instances differ").

First the plain fit of every class (``pipeline.method.gp_fit.fit_class_models``, unchanged: a class
with one training instance keeps it bit for bit, and the record says why it has no instance term).
Then, per (class, component) of a class with two or more training instances, the five log
hyperparameters t = log(a, ℓ, σ², b, λ) maximise the marginal likelihood of the joint covariance
over all the class's training views, ``K = a·E_ℓ + B ∘ b·E_λ + σ² I`` (B: same instance), times the
plain fit's weak priors on ℓ and σ² (``models.hyperprior``; none on b and λ: a vanishing b and a
constant offset, λ at its upper bound, are both answers the data may give). Starts: the plain fit
with its noise split in half between σ² and b (λ = ℓ, and λ long), then ``restarts`` draws
log-uniform in the bounds. The record adds b, λ, b / a, the plain (pooled) fit it started from, and a
95 % Laplace interval of b (from the curvature of the log objective in t at the optimum: over
training sets drawn from the fitted model, to the Laplace approximation's accuracy).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from pipeline.infra.config import ModelsConfig
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_instance import InstanceGPClassModels, same_instance
from pipeline.method.gp_prior import LogInverseGamma, input_range

_DEFAULTS = ModelsConfig()
NAMES = ("amplitude", "length_scale", "noise", "instance_amplitude", "instance_length_scale")
Z95 = 1.959963984540054
NO_TERM = "one training instance: no identifiable instance term"


class JointObjective:
    """-(log marginal likelihood + log prior) of one (class, component) and its gradient in t."""

    def __init__(self, X: np.ndarray, y: np.ndarray, labels: np.ndarray, priors: dict[int, LogInverseGamma]):
        self.D2 = np.sum((X[:, None, :] - X[None, :, :]) ** 2, axis=-1)
        self.B = same_instance(labels)
        self.y = y
        self.priors = priors

    def lml(self, t: np.ndarray, grad: bool = True):
        from scipy.linalg import cho_solve

        a, ell, sn2, b, lam = np.exp(t)
        Eg = a * np.exp(-self.D2 / (2 * ell * ell))
        Eh = self.B * (b * np.exp(-self.D2 / (2 * lam * lam)))
        K = Eg + Eh
        K[np.diag_indices(len(K))] += sn2
        try:
            L = np.linalg.cholesky(K)
        except np.linalg.LinAlgError:
            return (-np.inf, np.zeros(5)) if grad else -np.inf
        alpha = cho_solve((L, True), self.y)
        value = -0.5 * self.y @ alpha - np.log(np.diag(L)).sum() - 0.5 * len(self.y) * np.log(2 * np.pi)
        if not grad:
            return value
        W = np.outer(alpha, alpha) - cho_solve((L, True), np.eye(len(K)))
        dK = (Eg, Eg * self.D2 / (ell * ell), None, Eh, Eh * self.D2 / (lam * lam))
        g = np.array([0.5 * np.sum(W * d) if d is not None else 0.5 * sn2 * np.trace(W) for d in dK])
        return value, g

    def __call__(self, t: np.ndarray):
        value, g = self.lml(t)
        if not np.isfinite(value):
            return 1e300, np.zeros(5)
        for i, prior in self.priors.items():
            lp, dlp = prior(t[i])
            value += lp
            g = g.copy()
            g[i] += dlp
        return -value, -g

    def laplace_sd(self, t: np.ndarray, step: float = 1e-4) -> np.ndarray | None:
        """Standard deviations of t from the inverse Hessian of the objective (central differences
        of the analytic gradient), or None where the Hessian is not positive definite."""
        H = np.empty((5, 5))
        for j in range(5):
            e = np.zeros(5)
            e[j] = step
            H[j] = (self(t + e)[1] - self(t - e)[1]) / (2 * step)
        H = 0.5 * (H + H.T)
        try:
            np.linalg.cholesky(H)
        except np.linalg.LinAlgError:
            return None
        return np.sqrt(np.diag(np.linalg.inv(H)))


def fit_instance_models(X_by_class: Sequence[np.ndarray], Y_by_class: Sequence[np.ndarray],
                        instances_by_class: Sequence[np.ndarray], classes: Sequence[str], components: Sequence[int],
                        *, restarts: int = _DEFAULTS.restarts,
                        amplitude_bounds: tuple[float, float] = _DEFAULTS.amplitude_bounds,
                        length_scale_bounds: tuple[float, float] = _DEFAULTS.length_scale_bounds,
                        noise_bounds: tuple[float, float] = _DEFAULTS.noise_bounds, seed: int = _DEFAULTS.seed,
                        noise_floor: np.ndarray | None = None, hyperprior: str = _DEFAULTS.hyperprior,
                        noise_prior: tuple[float, float] = _DEFAULTS.noise_prior, **plain_kw
                        ) -> tuple[InstanceGPClassModels, list[dict[str, Any]]]:
    """The plain fit (``fit_class_models``, every keyword passed on) plus, where a class has two or
    more training instances, the joint fit with the instance term. ``instances_by_class[c]``
    (N_c,): any hashable labels of class c's training views (object folder names, integers).
    Returns ``InstanceGPClassModels`` and one record per fit (the plain record extended)."""
    C, F = len(classes), len(components)
    if len(instances_by_class) != C:
        raise ValueError(f"fit_instance_models: {C} classes but {len(instances_by_class)} instance label sets")
    labels = []
    for c, lab in enumerate(instances_by_class):
        lab = np.asarray(lab)
        if lab.ndim != 1 or len(lab) != len(X_by_class[c]):
            raise ValueError(f"fit_instance_models: class {classes[c]!r}: {len(X_by_class[c])} training views but "
                             f"instance labels of shape {lab.shape}")
        labels.append(np.unique(lab, return_inverse=True)[1].astype(np.int64))
    plain, diags = fit_class_models(X_by_class, Y_by_class, classes, components, restarts=restarts,
                                    amplitude_bounds=amplitude_bounds, length_scale_bounds=length_scale_bounds,
                                    noise_bounds=noise_bounds, seed=seed, noise_floor=noise_floor,
                                    hyperprior=hyperprior, noise_prior=noise_prior, **plain_kw)
    amp, ell, noise = plain.amplitude.copy(), plain.length_scale.copy(), plain.noise.copy()
    b, lam = np.zeros((C, F)), np.ones((C, F))
    noise_law = LogInverseGamma.between(*noise_prior) if hyperprior != "none" else None
    for c in range(C):
        n_inst = int(labels[c].max()) + 1
        for f in range(F):
            d = diags[c * F + f]
            d.update(n_instances=n_inst, instance_term=n_inst > 1)
            if n_inst < 2:
                d.update(instance_amplitude=0.0, instance_length_scale=None, instance_ratio=0.0,
                         instance_note=NO_TERM)
                continue
            X = np.asarray(X_by_class[c], float)
            priors = {} if noise_law is None else {1: LogInverseGamma.between(*input_range(X)), 2: noise_law}
            nb = tuple(d["noise_bounds"])
            bounds = [amplitude_bounds, length_scale_bounds, nb, amplitude_bounds, length_scale_bounds]
            obj = JointObjective(X - X.mean(axis=0), np.asarray(Y_by_class[c], float)[f] - plain.mean[c, f],
                                 labels[c], priors)
            res, t = _optimise(obj, plain, c, f, bounds, restarts, seed)
            amp[c, f], ell[c, f], noise[c, f], b[c, f], lam[c, f] = np.exp(t)
            sd = obj.laplace_sd(t)
            at_bound = [f"{n} at {'lower' if abs(t[i] - np.log(lo)) < 0.01 else 'upper'} bound"
                        for i, (n, (lo, hi)) in enumerate(zip(NAMES, bounds))
                        if min(abs(t[i] - np.log(lo)), abs(t[i] - np.log(hi))) < 0.01]
            d.update(
                pooled={n: d[n] for n in ("amplitude", "length_scale", "noise", "log_marginal_likelihood")},
                **{n: float(v) for n, v in zip(NAMES, np.exp(t))},
                instance_ratio=float(b[c, f] / amp[c, f]),
                instance_amplitude_ci=None if sd is None else [float(np.exp(t[3] - Z95 * sd[3])),
                                                               float(np.exp(t[3] + Z95 * sd[3]))],
                instance_ci_over="training sets from the fitted model (Laplace, log scale)",
                log_marginal_likelihood=float(obj.lml(t, grad=False)),
                log_prior=float(sum(p(t[i])[0] for i, p in priors.items())) if priors else None,
                at_bound=at_bound, warnings=d["warnings"] + ([] if res.success else [f"instance fit: {res.message}"]),
            )
    models = InstanceGPClassModels(plain.classes, plain.components, plain.X, plain.Y, plain.mean, amp, ell, noise,
                                   instances=labels, instance_amplitude=b, instance_length_scale=lam,
                                   component_names=plain.component_names, meta=plain.meta)
    return models, diags


def _optimise(obj: JointObjective, plain, c: int, f: int, bounds, restarts: int, seed: int):
    """The best L-BFGS-B run over the fixed starts and ``restarts`` seeded random ones."""
    from scipy import optimize

    lo, hi = np.log(np.array(bounds, float)).T
    a, ell, sn2 = plain.amplitude[c, f], plain.length_scale[c, f], plain.noise[c, f]
    starts = [np.log([a, ell, sn2 / 2, sn2 / 2, ell]), np.log([a, ell, sn2 / 2, sn2 / 2, np.exp(hi[4]) / 2])]
    rng = np.random.default_rng(np.random.SeedSequence([seed, c, f, 46]))
    starts += [rng.uniform(lo, hi) for _ in range(restarts)]
    best = None
    for t0 in starts:
        res = optimize.minimize(obj, np.clip(t0, lo, hi), jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)))
        if best is None or res.fun < best.fun:
            best = res
    return best, np.clip(best.x, lo, hi)
