"""The functions behind ``import viewfuse``: thin, documented wrappers over the internal packages
with arrays in and arrays out (docs/api.md)."""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.engine import population_block
from pipeline.method import registry
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.gp_instance_fit import fit_instance_models

# The evaluate stage's defaults (configs/synthetic.toml [evaluate]): confident error at max P >= 0.99, 15 ECE bins.
DEFAULT_PARAMS = M.Params(0.99, 15)


def methods(*, attribution: bool = False) -> list[str]:
    """The registered methods' keys, in order (built-ins first, then yours)."""
    return list(registry.keys(attribution=attribution))


def method(key: str) -> registry.FusionMethod:
    """The registered method ``key`` (a KeyError names the known ones)."""
    m = registry.get(key)
    if m is None:
        raise KeyError(f"no fusion method {key!r} (registered: {', '.join(registry.keys(attribution=True))})")
    return m


def fit_models(samples: Mapping[str, tuple[np.ndarray, np.ndarray]], *, components: Sequence[int] | None = None,
               restarts: int = 2, seed: int = 0, instances: Mapping[str, Sequence] | None = None,
               **fit) -> GPClassModels:
    """One GP per (class, score component) over the viewing direction, from your own samples.

    ``samples``: {class name: (angles (N,) in radians, the direction the object is seen from in
    its own frame; scores (N, D), the classifier's score vector of each view)}. ``components``:
    which of the D scores to model (default: all). Other keyword arguments go to
    ``pipeline.method.gp_fit.fit_class_models`` (bounds, hyperprior). Returns ``GPClassModels``
    (their fit diagnostics on ``.diagnostics``). ``instances``: {class: (N,) labels naming the
    object instance of each view} (a class left out is one instance): the models then carry an
    instance term (``InstanceGPClassModels``, docs/design.md §5, "Instances differ")."""
    if not samples:
        raise ValueError("fit_models: no classes given")
    classes = list(samples)
    X, Y = [], []
    for c in classes:
        ang, sc = (np.asarray(a, float) for a in samples[c])
        if ang.ndim != 1 or sc.ndim != 2 or len(ang) != len(sc):
            raise ValueError(f"fit_models: class {c!r} needs angles (N,) and scores (N, D), got {ang.shape} and {sc.shape}")
        X.append(np.stack([np.cos(ang), np.sin(ang)], axis=1))
        Y.append(sc.T)
    dims = {y.shape[0] for y in Y}
    if len(dims) != 1:
        raise ValueError(f"fit_models: every class needs the same score length, got {sorted(dims)}")
    comps = list(range(dims.pop())) if components is None else [int(f) for f in components]
    Y = [y[comps] for y in Y]
    if instances is not None:
        unknown = sorted(set(instances) - set(classes))
        if unknown:
            raise ValueError(f"fit_models: instances name class {unknown[0]!r}, which has no samples")
        labels = [np.zeros(len(x), int) if c not in instances else np.asarray(instances[c]) for c, x in zip(classes, X)]
        models, diagnostics = fit_instance_models(X, Y, labels, classes, comps, restarts=restarts, seed=seed,
                                                  progress=False, **fit)
    else:
        models, diagnostics = fit_class_models(X, Y, classes, comps, restarts=restarts, seed=seed, progress=False,
                                               **fit)
    models.diagnostics = diagnostics
    return models


def fuse(key: str, models: GPClassModels | None = None, *, cameras, object_xy=(0.0, 0.0), object_yaw: float = 0.0,
         dropout, own=None, probs=None, dirichlet=None, sigma: float = 0.0, n_x: int = 1, seed=0,
         var_floor: float = 1e-6, n_ss: int = 100) -> np.ndarray:
    """Fuse one track with the registered method ``key``: log posteriors after every step.

    ``cameras``: pose estimates (K, 2), or (R, K, 2) for R realizations, ground frame;
    ``object_xy`` (2,) and ``object_yaw`` (rad) place the object; ``dropout`` (K, N_s, F): each
    view's MC-dropout scores at the models' components (N_s = 1 for a deterministic classifier).
    ``own`` (K, N_s, C): each candidate's own score (Simple Bayes); ``probs`` (K, N_s, D) and
    ``dirichlet`` (``DirichletModels``): the Dirichlet method. ``sigma`` and ``n_x``: the pose
    samples With Uncertainty averages over (N(estimate, sigma² I), drawn from ``seed``).
    ``models`` with an instance term (``fit_models(..., instances=...)``) also serve the
    ``*_instance`` methods. Returns (K, C), or (R, K, C) for (R, K, 2) cameras."""
    m = method(key)
    cams = np.asarray(cameras, float)
    single = cams.ndim == 2
    est = cams[None] if single else cams
    drop = np.asarray(dropout, float)
    if drop.ndim != 3 or drop.shape[0] != est.shape[1]:
        raise ValueError(f"fuse: dropout must be (K, N_s, F) with K = {est.shape[1]} views, got {drop.shape}")
    obj = np.asarray(object_xy, float)
    t = registry.TrackInput(
        dropout=drop, gp=models, gp_instance=models if isinstance(models, InstanceGPClassModels) else None,
        dirichlet=dirichlet, own=None if own is None else np.asarray(own, float),
        probs=None if probs is None else np.asarray(probs, float), estimates=est,
        samples=sample_localization(est, sigma, n_x, np.random.default_rng(seed)),
        inputs=lambda p: relative_inputs(p, obj, object_yaw, unit_circle=True), var_floor=var_floor, n_ss=n_ss,
        rng=np.random.default_rng(seed))
    if not m.applies(t):
        raise ValueError(f"fuse: {key!r} needs {sorted(m.needs)}; missing: {sorted(n for n in m.needs if not t.has(n))}")
    out = m.fuse(t)
    if not m.uses_poses:
        out = np.broadcast_to(out, (len(est),) + out.shape).copy()
    return out[0] if single else out


def track_metrics(log_posteriors, truth: int, params: M.Params = DEFAULT_PARAMS) -> dict[str, float]:
    """Every metric of the evaluation (``pipeline.evaluation.metrics.spec.METRICS``) of one track's
    log posteriors (K, C) or (R, K, C) against the true class index."""
    lp = np.asarray(log_posteriors, float)
    return M.posterior_metrics(lp[None] if lp.ndim == 2 else lp, int(truth), params=params, is_log=True)


def evaluate_population(results: pd.DataFrame, *, metrics: Sequence[str] | None = None,
                        comparisons: Sequence[tuple[str, str]] | None = None, n_boot: int = 2000, seed: int = 0,
                        params: M.Params = DEFAULT_PARAMS) -> dict:
    """Pooled values with 95 % CIs, paired differences and verdict records over a population.

    ``results``: one row per (target, track, setting, method) with a column per metric (e.g. from
    ``track_metrics``), or the evaluate stage's results table (one row per realization and step,
    with ``realization``, ``step``, ``posterior`` and ``truth``), reduced to those rows here.
    CIs resample targets, then tracks within targets (``pipeline.evaluation.statistics``).
    ``comparisons``: (method, baseline) pairs (default: the registry's, of the methods present)."""
    cells = _cells(results, params) if "posterior" in results.columns else results.copy()
    for col in ("target", "track", "method"):
        if col not in cells.columns:
            raise ValueError(f"evaluate_population: the results table has no {col!r} column")
    if "setting" not in cells.columns:
        cells["setting"] = "default"
    present = list(dict.fromkeys(cells["method"]))
    order = [m for m in registry.keys(attribution=True) if m in present] + [m for m in present
                                                                             if registry.get(m) is None]
    keys = list(metrics) if metrics is not None else [k for k in M.METRICS if k in cells.columns]
    pairs = [tuple(c) for c in (comparisons if comparisons is not None else registry.comparisons())
             if c[0] in present and c[1] in present]
    return population_block(cells, order, keys, pairs, n_boot, seed)


def _cells(rows: pd.DataFrame, params: M.Params) -> pd.DataFrame:
    out = []
    for (target, track, setting, m), g in rows.groupby(["target", "track", "setting", "method"], sort=True):
        g = g.sort_values(["realization", "step"])
        R, K = g["realization"].nunique(), g["step"].nunique()
        post = np.stack(g["posterior"].to_numpy()).reshape(R, K, -1)
        truth = int(g["truth"].iloc[0])
        out.append({"target": target, "track": track, "setting": setting, "method": m,
                    **M.posterior_metrics(post, truth, params=params, is_log=False)})
    return pd.DataFrame(out)
