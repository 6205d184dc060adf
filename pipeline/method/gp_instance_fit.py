"""Fitting the class GPs with an instance term (``pipeline/method/gp_instance.py``; docs/design.md §5,
"Instances differ").

First the plain fit of every class (``pipeline.method.gp_fit.fit_class_models``, unchanged: a class
with one training instance keeps it bit for bit, and the record says why it has no instance term).
Then, per (class, component) of a class with two or more training instances, the five log
hyperparameters t = log(a, ℓ, σ², b, λ) maximise the marginal likelihood of the joint covariance
over all the class's training views, ``K = a·E_ℓ + B ∘ b·E_λ + σ² I`` (B: same instance), times the
plain fit's weak priors on ℓ and σ² (``models.hyperprior``) and, with ``instance_prior = "split"``
(``models.instance_prior``), a Beta prior on the variance split b / (a + b) (``split_prior``, through
its logit log b - log a) and ℓ's inverse-gamma law on λ; with "none" no prior on b and λ: a
vanishing b and a constant offset, λ at its upper bound, are both answers the data may give
(measured on ETH-80: docs/results.md, "Instance term: a prior on the variance split"). Starts: the plain fit
with its noise split in half between σ² and b (λ = ℓ, and λ long), then ``restarts`` draws
log-uniform in the bounds. The record adds b, λ, b / a, the plain (pooled) fit it started from, and a
95 % Laplace interval of b (from the curvature of the log objective in t at the optimum: over
training sets drawn from the fitted model, to the Laplace approximation's accuracy; none where the
curvature is not positive or the interval overflows). The joint fits run all at once by default
(``pipeline/method/gp_instance_batch.py``); one at a time (``instance_route = "per_fit"``) is the
reference.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from pipeline.infra import seeds
from pipeline.infra.config import ModelsConfig
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_instance import InstanceGPClassModels, same_instance
from pipeline.method.gp_instance_batch import laplace_from_hessian
from pipeline.method.gp_prior import LogInverseGamma, LogitBeta, input_range
from pipeline.method.gp_batch import prior_rows
from pipeline.method.gp_instance_batch import InstanceProblem, fit_instance_problems, instance_prior_rows

_DEFAULTS = ModelsConfig()
NAMES = ("amplitude", "length_scale", "noise", "instance_amplitude", "instance_length_scale")
Z95 = 1.959963984540054
NO_TERM = "one training instance: no identifiable instance term"
INSTANCE_ROUTES = ("batch", "per_fit")
INSTANCE_PRIORS = ("none", "split")


class JointObjective:
    """-(log marginal likelihood + log prior) of one (class, component) and its gradient in t."""

    def __init__(self, X: np.ndarray, y: np.ndarray, labels: np.ndarray, priors: dict[int, LogInverseGamma],
                 split: LogitBeta | None = None):
        self.X = X
        self.D2 = np.sum((X[:, None, :] - X[None, :, :]) ** 2, axis=-1)
        self.B = same_instance(labels)
        self.y = y
        self.priors = priors       # index of t -> its law (1: ℓ, 2: σ², 4: λ)
        self.split = split         # the law of log b - log a, or None

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
        if self.split is not None:
            lp, dlp = self.split(t[3] - t[0])
            value += lp
            g = g.copy()
            g[3] += dlp
            g[0] -= dlp
        return -value, -g

    def log_prior(self, t: np.ndarray) -> float | None:
        if not self.priors and self.split is None:
            return None
        return float(sum(p(t[i])[0] for i, p in self.priors.items())
                     + (self.split(t[3] - t[0])[0] if self.split is not None else 0.0))

    def laplace_sd(self, t: np.ndarray, step: float = 1e-4) -> np.ndarray | None:
        """Standard deviations of t from the inverse Hessian of the objective (central differences
        of the analytic gradient), or None where the Hessian is not positive definite."""
        H = np.empty((5, 5))
        for j in range(5):
            e = np.zeros(5)
            e[j] = step
            H[j] = (self(t + e)[1] - self(t - e)[1]) / (2 * step)
        return laplace_from_hessian(H)


def fit_instance_models(X_by_class: Sequence[np.ndarray], Y_by_class: Sequence[np.ndarray],
                        instances_by_class: Sequence[np.ndarray], classes: Sequence[str], components: Sequence[int],
                        *, restarts: int = _DEFAULTS.restarts,
                        amplitude_bounds: tuple[float, float] = _DEFAULTS.amplitude_bounds,
                        length_scale_bounds: tuple[float, float] = _DEFAULTS.length_scale_bounds,
                        noise_bounds: tuple[float, float] = _DEFAULTS.noise_bounds, seed: int = _DEFAULTS.seed,
                        noise_floor: np.ndarray | None = None, hyperprior: str = _DEFAULTS.hyperprior,
                        noise_prior: tuple[float, float] = _DEFAULTS.noise_prior, route: str = "batch",
                        instance_route: str | None = None, instance_prior: str = "none",
                        split_prior: tuple[float, float] = (2.0, 2.0), **plain_kw
                        ) -> tuple[InstanceGPClassModels, list[dict[str, Any]]]:
    """The plain fit (``fit_class_models``, ``route`` and every other keyword passed on) plus, where
    a class has two or more training instances, the joint fit with the instance term.
    ``instances_by_class[c]`` (N_c,): any hashable labels of class c's training views (object
    folder names, integers). ``instance_route``: "batch" (every joint fit at once,
    ``pipeline/method/gp_instance_batch.py``) or "per_fit" (one scipy L-BFGS-B at a time, the
    reference the tests and ``tests/bench/bench_gp_instance.py`` compare against); by default "batch"
    with ``route = "batch"``, else "per_fit". ``instance_prior``: "none" or "split" (a
    Beta(``split_prior``) law on b / (a + b) and ℓ's inverse-gamma range on λ). Returns ``InstanceGPClassModels`` and one record per
    fit (the plain record extended)."""
    C, F = len(classes), len(components)
    instance_route = instance_route or ("batch" if route == "batch" else "per_fit")
    if instance_route not in INSTANCE_ROUTES:
        raise ValueError(f"fit_instance_models: instance_route must be one of {INSTANCE_ROUTES}, got {instance_route!r}")
    if instance_prior not in INSTANCE_PRIORS:
        raise ValueError(f"fit_instance_models: instance_prior must be one of {INSTANCE_PRIORS}, got {instance_prior!r}")
    split_prior = tuple(float(v) for v in split_prior)
    if len(split_prior) != 2 or not all(np.isfinite(v) and v > 0 for v in split_prior):
        raise ValueError(f"fit_instance_models: split_prior must be two positive Beta shapes, got {split_prior}")
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
                                    hyperprior=hyperprior, noise_prior=noise_prior, route=route, **plain_kw)
    amp, ell, noise = plain.amplitude.copy(), plain.length_scale.copy(), plain.noise.copy()
    b, lam = np.zeros((C, F)), np.ones((C, F))
    noise_law = LogInverseGamma.between(*noise_prior) if hyperprior != "none" else None
    jobs = []     # (c, f, objective, bounds, starts) of every fit with an instance term
    for c in range(C):
        n_inst = int(labels[c].max()) + 1
        X = np.asarray(X_by_class[c], float)
        ell_law = LogInverseGamma.between(*input_range(X)) if n_inst > 1 else None
        priors = {} if noise_law is None or n_inst < 2 else {1: ell_law, 2: noise_law}
        split = None
        if instance_prior == "split" and n_inst > 1:
            priors[4], split = ell_law, LogitBeta(*split_prior)
        for f in range(F):
            d = diags[c * F + f]
            d.update(n_instances=n_inst, instance_term=n_inst > 1)
            if n_inst < 2:
                d.update(instance_amplitude=0.0, instance_length_scale=None, instance_ratio=0.0,
                         instance_note=NO_TERM)
                continue
            bounds = [amplitude_bounds, length_scale_bounds, tuple(d["noise_bounds"]), amplitude_bounds,
                      length_scale_bounds]
            obj = JointObjective(X - X.mean(axis=0), np.asarray(Y_by_class[c], float)[f] - plain.mean[c, f],
                                 labels[c], priors, split)
            jobs.append((c, f, obj, bounds, _starts(plain, c, f, bounds, restarts, seed)))
    from threadpoolctl import threadpool_limits

    # One BLAS thread for both routes: matrices of a few hundred rows at most, whose BLAS threads
    # only spin against each other (and the stage's other processes) on a loaded machine.
    with threadpool_limits(1, user_api="blas"):
        fits = (_fit_batched if instance_route == "batch" else _fit_each)(jobs, labels)
        records = [float(obj.lml(t, grad=False)) for (_, _, obj, _, _), (t, *_) in zip(jobs, fits)]
    for (c, f, obj, bounds, _), (t, sd, warn, record), lml in zip(jobs, fits, records):
        d = diags[c * F + f]
        amp[c, f], ell[c, f], noise[c, f], b[c, f], lam[c, f] = np.exp(t)
        at_bound = [f"{n} at {'lower' if abs(t[i] - np.log(lo)) < 0.01 else 'upper'} bound"
                    for i, (n, (lo, hi)) in enumerate(zip(NAMES, bounds))
                    if min(abs(t[i] - np.log(lo)), abs(t[i] - np.log(hi))) < 0.01]
        d.update(
            pooled={n: d[n] for n in ("amplitude", "length_scale", "noise", "log_marginal_likelihood")},
            **{n: float(v) for n, v in zip(NAMES, np.exp(t))},
            instance_ratio=float(b[c, f] / amp[c, f]),
            instance_amplitude_ci=_laplace_ci(t[3], sd),
            instance_ci_over="training sets from the fitted model (Laplace, log scale)",
            log_marginal_likelihood=lml,
            log_prior=obj.log_prior(t),
            instance_prior=None if obj.split is None else {"split": obj.split.describe(),
                                                           "instance_length_scale": obj.priors[4].describe()},
            at_bound=at_bound, warnings=d["warnings"] + warn, instance_optimizer=record,
        )
    models = InstanceGPClassModels(plain.classes, plain.components, plain.X, plain.Y, plain.mean, amp, ell, noise,
                                   instances=labels, instance_amplitude=b, instance_length_scale=lam,
                                   component_names=plain.component_names, meta=plain.meta)
    return models, diags


def _laplace_ci(t3: float, sd: np.ndarray | None) -> list[float] | None:
    """The 95 % Laplace interval of b, or None where there is none: a Hessian that is not positive
    definite, or a curvature so flat in log b that the interval overflows (no finite bound to write)."""
    if sd is None:
        return None
    with np.errstate(over="ignore"):
        ci = np.exp([t3 - Z95 * sd[3], t3 + Z95 * sd[3]])
    return [float(v) for v in ci] if np.all(np.isfinite(ci)) else None


def _starts(plain, c: int, f: int, bounds, restarts: int, seed: int) -> np.ndarray:
    """The fixed starts (the plain fit, its noise split in half between σ² and b; λ = ℓ, and λ
    long), then ``restarts`` seeded log-uniform draws in the bounds; all clipped into them."""
    lo, hi = np.log(np.array(bounds, float)).T
    a, ell, sn2 = plain.amplitude[c, f], plain.length_scale[c, f], plain.noise[c, f]
    starts = [np.log([a, ell, sn2 / 2, sn2 / 2, ell]), np.log([a, ell, sn2 / 2, sn2 / 2, np.exp(hi[4]) / 2])]
    rng = seeds.stream(seed, int(c), int(f), 46)  # 46: the restarts' stream
    starts += [rng.uniform(lo, hi) for _ in range(restarts)]
    return np.clip(np.array(starts), lo, hi)


def _fit_each(jobs, labels):
    """The reference: per fit, L-BFGS-B from each start, the best kept; its Laplace sd."""
    out = []
    for c, f, obj, bounds, starts in jobs:
        res, t = _optimise(obj, bounds, starts)
        out.append((t, obj.laplace_sd(t), [] if res.success else [f"instance fit: {res.message}"],
                    {"route": "per_fit"}))
    return out


def _fit_batched(jobs, labels):
    """Every fit at once (``gp_instance_batch``); a run that did not converge is a warning, as
    the per-fit route's best run is."""

    problems = [InstanceProblem(obj.X, obj.y, labels[c], np.log(np.array(bounds, float)),
                                prior_rows({i: p for i, p in obj.priors.items() if i in (1, 2)}, 1, 2), starts,
                                instance_prior_rows(obj.split, obj.priors.get(4)))
                for c, f, obj, bounds, starts in jobs]
    results, stack = fit_instance_problems(problems)
    sds = stack.laplace_sd(np.stack([r.theta for r in results])) if results else []
    out = []
    for r, sd in zip(results, sds):
        warn = [f"instance fit: {r.runs[r.start]['message']}"] if r.runs[r.start]["status"] != 0 else []
        out.append((r.theta, sd, warn, {"route": "batch", "objective": r.objective, "start": r.start,
                                        "runs": [{k: x[k] for k in ("status", "nit", "nfev")} for x in r.runs]}))
    return out


def _optimise(obj: JointObjective, bounds, starts: np.ndarray):
    """The best L-BFGS-B run over the starts."""
    from scipy import optimize

    lo, hi = np.log(np.array(bounds, float)).T
    best = None
    for t0 in starts:
        res = optimize.minimize(obj, t0, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)))
        if best is None or res.fun < best.fun:
            best = res
    return best, np.clip(best.x, lo, hi)
