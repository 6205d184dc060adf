"""The functions behind ``import viewfuse``: thin, documented wrappers over the internal packages
with arrays in and arrays out (docs/api.md)."""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.engine import population_block
from pipeline.evaluation.statistics.hierarchy import CLUSTERS
from pipeline.method import registry
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_fit import _DEFAULTS as FIT_DEFAULTS, fit_class_models
from pipeline.method.output_check import call_checked, problem
from pipeline.method.provider import providers
from viewfuse import _args as A
from pipeline.method.gp_instance_fit import fit_instance_models
from pipeline.method.gp_prior import input_range
from pipeline.infra import footprints
from pipeline.evaluation.statistics.resampler import draw_seconds

# The evaluate stage's defaults (configs/synthetic.toml [evaluate]): confident error at max P >= 0.99, 15 ECE bins.
DEFAULT_PARAMS = M.Params(0.99, 15)


class UnknownMethodError(KeyError, ValueError):
    """``method(key)`` of a key that is not registered: a KeyError (as a lookup) and a ValueError
    (as a bad argument), its message shown as written."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def methods(*, attribution: bool = False) -> list[str]:
    """The registered methods' keys, in order (built-ins first, then yours)."""
    if not isinstance(attribution, (bool, np.bool_)):
        raise TypeError(f"methods: attribution must be True or False, got {type(attribution).__name__}")
    return list(registry.keys(attribution=bool(attribution)))


def method(key: str) -> registry.FusionMethod:
    """The registered method ``key`` (an ``UnknownMethodError``, a KeyError and a ValueError,
    names the known ones)."""
    A.string("method", "key", key)
    m = registry.get(key)
    if m is None:
        raise UnknownMethodError(f"method: key {key!r} is no registered fusion method "
                                 f"(registered: {', '.join(registry.keys(attribution=True))})")
    return m


# fit_models' memory: each GP fit holds a few N x N float64 matrices (kernel, its Cholesky factor,
# the gradient's solve); N the largest class's sample count.
FIT_BYTES_PER_N2 = 4 * 8


def fit_models(samples: Mapping[str, tuple[np.ndarray, np.ndarray]], *, components: Sequence[int] | None = None,
               restarts: int = 2, seed: int = 0, instances: Mapping[str, Sequence] | None = None,
               **fit) -> GPClassModels:
    """One GP per (class, score component) over the viewing direction, from your own samples.

    ``samples``: {class name: (angles (N,) in radians, the direction the object is seen from in
    its own frame; scores (N, D), the classifier's score vector of each view)}. ``components``:
    which of the D scores to model (distinct indices in [0, D); default: all). Other keyword
    arguments go to ``pipeline.method.gp_fit.fit_class_models`` (bounds, hyperprior). Returns
    ``GPClassModels`` (their fit diagnostics on ``.diagnostics``). Refused before any fit: a class
    whose N x N matrices (``FIT_BYTES_PER_N2`` bytes per entry) exceed the memory available.
    ``instances``: {class: (N,) labels naming the object instance of each view} (a class left out
    is one instance): the models then carry an instance term (``InstanceGPClassModels``,
    docs/design.md §5, "Instances differ")."""
    fn = "fit_models"
    A.instance(fn, "samples", samples, Mapping, "a mapping {class name: (angles, scores)}")
    if not samples:
        raise ValueError("fit_models: samples has no classes")
    classes = list(samples)
    X, Y = [], []
    for c in classes:
        if not isinstance(c, str) or not c:
            raise TypeError(f"fit_models: samples' keys must be non-empty class names (str), got {c!r:.60}")
        pair = samples[c]
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise TypeError(f"fit_models: samples[{c!r}] must be a pair (angles, scores), got {type(pair).__name__}")
        ang = A.array(fn, f"samples[{c!r}] angles", pair[0], ndim=1, dims="(N,) radians")
        sc = A.array(fn, f"samples[{c!r}] scores", pair[1], ndim=2, shape=(len(ang), None), dims="(N, D)")
        X.append(np.stack([np.cos(ang), np.sin(ang)], axis=1))
        Y.append(sc.T)
    dims = {y.shape[0] for y in Y}
    if len(dims) != 1:
        raise ValueError(f"fit_models: samples: every class needs the same score length D, got {sorted(dims)}")
    D = dims.pop()
    if components is None:
        comps = list(range(D))
    else:
        if isinstance(components, (str, bytes)) or not isinstance(components, Sequence | np.ndarray):
            raise TypeError(f"fit_models: components must be a sequence of score indices, got {type(components).__name__}")
        comps = [A.integer(fn, "components", f, lo=0, hi=D - 1) for f in components]
        if not comps:
            raise ValueError("fit_models: components must name at least one score index")
        if len(set(comps)) != len(comps):
            raise ValueError(f"fit_models: components has repeated indices: {comps}")
    A.integer(fn, "restarts", restarts, lo=0, hi=1000)
    A.integer(fn, "seed", seed, lo=0)
    _spread_enough(fn, classes, X, fit.get("hyperprior", FIT_DEFAULTS.hyperprior) != "none")
    n_max = max(len(x) for x in X)
    A.affordable(fn, "samples", FIT_BYTES_PER_N2 * float(n_max) ** 2)
    Y = [y[comps] for y in Y]
    if instances is not None:
        A.instance(fn, "instances", instances, Mapping, "a mapping {class name: (N,) instance labels}")
        unknown = sorted(set(instances) - set(classes), key=repr)
        if unknown:
            raise ValueError(f"fit_models: instances name class {unknown[0]!r}, which has no samples")
        labels = [np.zeros(len(x), int) if c not in instances else np.asarray(instances[c]) for c, x in zip(classes, X)]
        for c, x, lab in zip(classes, X, labels):
            if lab.ndim != 1 or len(lab) != len(x):
                raise ValueError(f"fit_models: instances[{c!r}] must hold one label per view ({len(x)},), "
                                 f"got shape {lab.shape}")
        models, diagnostics = fit_instance_models(X, Y, labels, classes, comps, restarts=restarts, seed=seed,
                                                  progress=False, **fit)
    else:
        models, diagnostics = fit_class_models(X, Y, classes, comps, restarts=restarts, seed=seed, progress=False,
                                               **fit)
    models.diagnostics = diagnostics
    return models


def _spread_enough(fn: str, classes: list[str], X: list[np.ndarray], prior: bool) -> None:
    """Each class's views must make a GP fit: at least two views, from at least two directions,
    and with the length-scale prior (``hyperprior``) at least two distinct distances between them
    (the prior spans the smallest to the largest): named here as the argument, not as the
    internal function that would fail (``input_range``, ``inverse_gamma_for``)."""

    for c, x in zip(classes, X):
        where = f"{fn}: samples[{c!r}] angles"
        if len(x) < 2:
            raise ValueError(f"{where}: {len(x)} view; a class needs at least 2")
        dirs = len(np.unique(np.round(x, 9), axis=0))
        if dirs < 2:
            raise ValueError(f"{where}: all {len(x)} views are from one direction; a class needs at least 2")
        if prior:
            lo, hi = input_range(x)
            if not lo < hi * (1 - 1e-9):
                raise ValueError(f"{where}: every pair of the {dirs} directions is {lo:.3g} apart, so the "
                                 "length-scale prior (hyperprior='inverse_gamma') has no range to span; "
                                 "add a view from another direction, or pass hyperprior='none'")


# fuse's cost, measured (With Uncertainty, after its first call in the process; tracemalloc peak
# and RSS growth, CPU s; 2-core AMD EPYC at load ~5): about FUSE_WORDS float64 a (realization,
# sample, step) whatever C and F (101 MB at R N_x K = 1.8e6 for C x F = 4 x 4, 8 x 2 and 2 x 8;
# 202 MB at 3.6e6), and FUSE_SECONDS per (trajectory, step, class, component) x K (9.4 s at
# R N_x = 2e5, K = 9, C F = 16; 14.2 s at C = 8, F = 2; 8.2 s at N_x = 2e4, K = 30; 21 s at
# R = 20, N_x = 2e4): the estimate within 0.6-1.8x of each. The first call in a process also
# compiles the engine (about 22 s, not counted: once a process).
FUSE_WORDS = 8
FUSE_SECONDS = 5e-8
MAX_SECONDS = 60.0
# A method call still running after this long is stopped (the evaluate stage's run.method_seconds default).
TIME_LIMIT = 600.0


def _within_arithmetic(fn: str, var_floor: float, **arrays) -> None:
    """Finite but huge arguments overflow inside every method (a squared score difference over
    ``var_floor``, a squared camera distance) and came out as the method's NaN output: refuse them
    here, as the caller's. Scores must keep (2|x|)² / var_floor finite, positions (4|x|)²."""
    big = np.finfo(float).max
    for name, a in arrays.items():
        if a is None or a.size == 0:
            continue
        pos = name in ("cameras", "object_xy")
        bound = np.sqrt(big) / 4 if pos else np.sqrt(big * var_floor) / 2
        worst = float(np.abs(a).max())
        if worst > bound:
            why = "a squared distance" if pos else f"a squared score difference over var_floor = {var_floor:g}"
            raise ValueError(f"{fn}: {name} holds {worst:.3g}, too large for the fusion's arithmetic ({why} would "
                             f"overflow float64; |values| must stay below {bound:.3g})")


def fuse(key: str, models: GPClassModels | None = None, *, cameras, object_xy=(0.0, 0.0), object_yaw: float = 0.0,
         dropout, own=None, probs=None, provided: dict | None = None, sigma: float = 0.0, n_x: int = 1, seed=0,
         var_floor: float = 1e-6, max_seconds: float | None = MAX_SECONDS,
         time_limit: float | None = TIME_LIMIT) -> np.ndarray:
    """Fuse one track with the registered method ``key``: log posteriors after every step.

    ``cameras``: pose estimates (K, 2), or (R, K, 2) for R realizations, ground frame;
    ``object_xy`` (2,) and ``object_yaw`` (rad) place the object; ``dropout`` (K, N_s, F): each
    view's MC-dropout scores at the models' components (N_s = 1 for a deterministic classifier).
    ``own`` (K, N_s, C): each candidate's own score (Simple Bayes); ``probs`` (K, N_s, D) the whole
    probability vectors; ``provided``: {provider key: models} for a method with a model of its own
    (``vf.providers()``; ``TrackInput.models``). ``sigma`` and ``n_x``: the pose
    samples With Uncertainty averages over (N(estimate, sigma² I), drawn from ``seed``).
    ``models`` with an instance term (``fit_models(..., instances=...)``) also serve the
    ``*_instance`` methods. Returns (K, C), or (R, K, C) for (R, K, 2) cameras, checked as every method's output is
    (``pipeline.method.output_check``). A call estimated over the available memory or over
    ``max_seconds`` (None: no bound) is refused before anything is drawn; a method still running
    after ``time_limit`` seconds (None: no limit; the main thread only) is stopped, named. The
    method reads read-only views of the arrays: your arrays are never changed."""
    fn = "fuse"
    m = method(key)
    if models is not None:
        A.instance(fn, "models", models, GPClassModels, "GPClassModels (from fit_models) or None")
    if provided is not None:
        A.instance(fn, "provided", provided, Mapping, "a mapping {provider key: models} or None")
        for k in provided:
            if k not in providers():
                raise ValueError(f"fuse: provided names {k!r}, not a registered model provider "
                                 f"(registered: {', '.join(providers()) or 'none'})")
    cams = A.array(fn, "cameras", cameras, ndim=(2, 3), shape=(None, 2), dims="(K, 2) or (R, K, 2)")
    single = cams.ndim == 2
    est = cams[None] if single else cams
    R, K = est.shape[:2]
    F = None if models is None else len(models.components)
    drop = A.array(fn, "dropout", dropout, ndim=3, shape=(K, None, F), dims=f"(K, N_s, F) with K = {K} views")
    C = None if models is None else len(models.classes)
    if own is not None:
        own = A.array(fn, "own", own, ndim=3, shape=(K, None, C), dims=f"(K, N_s, C) with K = {K}")
        C = own.shape[-1] if C is None else C
    if probs is not None:
        probs = A.array(fn, "probs", probs, ndim=3, shape=(K, None, None), dims=f"(K, N_s, D) with K = {K}")
    obj = A.array(fn, "object_xy", object_xy, ndim=1, shape=(2,), dims="(2,)")
    yaw = A.real(fn, "object_yaw", object_yaw)
    sigma = A.real(fn, "sigma", sigma, lo=0.0)
    n_x = A.integer(fn, "n_x", n_x, lo=1)
    if seed is not None:
        A.integer(fn, "seed", seed, lo=0)
    var_floor = A.real(fn, "var_floor", var_floor, lo=0.0, open_lo=True)
    if max_seconds is not None:
        max_seconds = A.real(fn, "max_seconds", max_seconds, lo=0.0, open_lo=True)
    _within_arithmetic(fn, var_floor, cameras=est, object_xy=obj, dropout=drop, own=own, probs=probs)
    if time_limit is not None:
        time_limit = A.real(fn, "time_limit", time_limit, lo=0.0, open_lo=True)
    units = float(R) * n_x * K * (C or 1) * drop.shape[2]
    A.affordable(fn, "n_x and cameras", 8.0 * FUSE_WORDS * R * n_x * K, FUSE_SECONDS * units * K, max_seconds)
    # a bank that is also a provider's model (``ModelProvider.serves``: one with an instance term) serves it too
    served = {p.key: models for p in providers().values() if models is not None and p.serves(models)}
    t = registry.TrackInput(
        dropout=drop, gp=models, models={**served, **(provided or {})}, own=own, probs=probs, estimates=est,
        samples=sample_localization(est, sigma, n_x, np.random.default_rng(seed)),
        inputs=lambda p: relative_inputs(p, obj, yaw, unit_circle=True), var_floor=var_floor,
        rng=np.random.default_rng(seed))
    if not m.applies(t):
        raise ValueError(f"fuse: {key!r} needs {sorted(m.needs)}; missing: {sorted(n for n in m.needs if not t.has(n))}")
    out = call_checked(m, "fuse", t, seconds=time_limit or 0.0, setting="vf.fuse(time_limit=...)")
    if not m.uses_poses:
        out = np.broadcast_to(out, (len(est),) + out.shape).copy()
    return out[0] if single else out


def _params(fn: str, params) -> M.Params:
    return A.instance(fn, "params", params, M.Params, "pipeline.evaluation.metrics.spec.Params")


def track_metrics(log_posteriors, truth: int, params: M.Params = DEFAULT_PARAMS) -> dict[str, float]:
    """Every metric of the evaluation (``pipeline.evaluation.metrics.spec.METRICS``) of one track's
    log posteriors (K, C) or (R, K, C) against the true class index. The posteriors must be what
    a method returns (``pipeline.method.output_check``: no NaN or +inf, each normalised)."""
    fn = "track_metrics"
    lp = A.array(fn, "log_posteriors", log_posteriors, ndim=(2, 3), dims="(K, C) or (R, K, C)", finite=False)
    lp = lp[None] if lp.ndim == 2 else lp
    bad = problem(lp, (None, None, None))
    if bad is not None:
        raise ValueError(f"{fn}: log_posteriors {bad}")
    truth = A.integer(fn, "truth", truth, lo=0, hi=lp.shape[-1] - 1)
    return M.posterior_metrics(lp, truth, params=_params(fn, params), is_log=True)


# evaluate_population's memory: the evaluate stage's rule (footprints.bootstrap: about nine
# (draws, targets, tracks per target) float64 arrays), which its measured peak meets within 2x
# (3 targets x 2 tracks, 2e6 draws: 0.90 GB against 0.86 estimated; 10 x 4, 5e5: 1.13 GB against
# 1.44; 30 x 8, 1e5: 1.15 GB against 1.73); a count of only the kept arrays said 0.26, 0.23, 0.22.
def _population_bytes(cells: pd.DataFrame, n_boot: int) -> float:

    tracks = cells.drop_duplicates(["target", "track"]).groupby("target").size()
    return footprints.bootstrap(n_boot, len(tracks), int(tracks.max()))


# its time: one statistic's draws timed (up to 20,000, scaled: resampler.draw_seconds) for each
# interval drawn, every metric for every method and comparison
def _population_seconds(cells: pd.DataFrame, n_stats: int, n_boot: int) -> float:

    tracks = cells.drop_duplicates(["target", "track"]).groupby("target").size()
    return n_stats * draw_seconds([list(tracks)], n_boot)


def evaluate_population(results: pd.DataFrame, *, metrics: Sequence[str] | None = None,
                        comparisons: Sequence[tuple[str, str]] | None = None, n_boot: int = 2000, seed: int = 0,
                        params: M.Params = DEFAULT_PARAMS, cluster: str = "target",
                        max_seconds: float | None = 600.0) -> dict:
    """Pooled values with 95 % CIs, paired differences and verdict records over a population.

    ``results``: one row per (target, track, setting, method) with a column per metric (e.g. from
    ``track_metrics``), or the evaluate stage's results table (one row per realization and step,
    with ``realization``, ``step``, ``posterior`` and ``truth``), reduced to those rows here.
    CIs of means are cluster-robust t intervals over the design's levels (``pipeline.evaluation.statistics.design``:
    targets, the scans a ``scan`` column names, categories with ``cluster="category"``), withheld
    (``withheld``: the reason; no verdict) where a level has fewer than 8 units; other statistics
    resample targets, then tracks within targets, or the design's clusters on top: ``cluster`` =
    "scan" | "category" | "crossed" (``evaluate.statistics.cluster``; "scan" and "crossed" need a
    ``scan`` column). docs/calibration.md measures their coverage.
    ``comparisons``: (method, baseline) pairs (default: the registry's, of the methods present).
    Refused: an empty or duplicated table, an unknown metric or one without a value for some
    method, a comparison naming a method the table lacks, an unknown clustering, a bootstrap over
    the available memory, or one estimated (a timed small draw, scaled) to take longer than
    ``max_seconds`` (None: no bound)."""
    fn = "evaluate_population"
    A.instance(fn, "results", results, pd.DataFrame, "a pandas DataFrame")
    if results.empty:
        raise ValueError(f"{fn}: results is empty (no rows)")
    n_boot = A.integer(fn, "n_boot", n_boot, lo=2)
    A.integer(fn, "seed", seed, lo=0)
    A.string(fn, "cluster", cluster)
    if cluster not in CLUSTERS:
        raise ValueError(f"{fn}: cluster must be one of {', '.join(CLUSTERS)}, got {cluster!r}")
    if cluster in ("scan", "crossed") and "scan" not in results.columns:
        raise ValueError(f"{fn}: cluster={cluster!r} needs a 'scan' column in results")
    params = _params(fn, params)
    cells = _cells(results, params) if "posterior" in results.columns else results.copy()
    for col in ("target", "track", "method"):
        if col not in cells.columns:
            raise ValueError(f"{fn}: results has no {col!r} column")
    if "setting" not in cells.columns:
        cells["setting"] = "default"
    ident = ["target", "track", "setting", "method"]
    if cells[ident].isna().any().any():
        raise ValueError(f"{fn}: results has missing values in its {ident} columns")
    track = pd.to_numeric(cells["track"], errors="coerce")
    odd = track.isna() | (track != np.floor(track))
    if odd.any():   # the resampling numbers tracks within a target; a label would fail deep inside it
        raise ValueError(f"{fn}: results' 'track' column must hold integer track numbers (within each target), got "
                         f"{cells.loc[odd, 'track'].iloc[0]!r:.40}; number text labels first, e.g. results['track'] = "
                         "results.groupby('target')['track'].transform(lambda s: pd.factorize(s)[0])")
    dup = cells.duplicated(ident)
    if dup.any():
        first = cells.loc[dup, ident].iloc[0].to_dict()
        raise ValueError(f"{fn}: results has {int(dup.sum())} duplicated row(s) for one (target, track, setting, "
                         f"method), e.g. {first}")
    present = list(dict.fromkeys(cells["method"]))
    order = [m for m in registry.keys(attribution=True) if m in present] + [m for m in present
                                                                             if registry.get(m) is None]
    keys = _metric_keys(fn, cells, metrics, present)
    pairs = _pairs(fn, comparisons, present)
    A.affordable(fn, "n_boot", _population_bytes(cells, n_boot))
    if max_seconds is not None:
        max_seconds = A.real(fn, "max_seconds", max_seconds, lo=0.0, open_lo=True)
        A.affordable(fn, "n_boot", 0.0, _population_seconds(cells, len(keys) * (len(order) + len(pairs)), n_boot),
                     max_seconds)
    return population_block(cells, order, keys, pairs, n_boot, seed, cluster=cluster)


def _metric_keys(fn: str, cells: pd.DataFrame, metrics, present) -> list[str]:
    if metrics is None:
        keys = [k for k in M.METRICS if k in cells.columns]
        if not keys:
            raise ValueError(f"{fn}: results has no metric column (known: {', '.join(M.METRICS)})")
    else:
        if isinstance(metrics, (str, bytes)) or not isinstance(metrics, Sequence):
            raise TypeError(f"{fn}: metrics must be a list of metric names, got {type(metrics).__name__}")
        keys = [A.string(fn, "metrics", k) for k in metrics]
        unknown = [k for k in keys if k not in M.METRICS]
        if unknown:
            raise ValueError(f"{fn}: metrics names unknown metric(s) {unknown} (known: {', '.join(M.METRICS)})")
        missing = [k for k in keys if k not in cells.columns]
        if missing:
            raise ValueError(f"{fn}: metrics names {missing}, which results has no column for")
        if not keys:
            raise ValueError(f"{fn}: metrics is empty")
    for k in keys:
        try:
            col = pd.to_numeric(cells[k], errors="raise").astype(float)
        except (TypeError, ValueError):
            raise TypeError(f"{fn}: results' metric column {k!r} is not numeric") from None
        for m in present:
            if col[cells["method"] == m].isna().all():
                raise ValueError(f"{fn}: results' metric column {k!r} has no value (all NaN) for method {m!r}")
    return keys


def _pairs(fn: str, comparisons, present) -> list[tuple[str, str]]:
    if comparisons is None:
        return [tuple(c) for c in registry.comparisons() if c[0] in present and c[1] in present]
    if isinstance(comparisons, (str, bytes)) or not isinstance(comparisons, Sequence):
        raise TypeError(f"{fn}: comparisons must be a list of (method, baseline) pairs, got {type(comparisons).__name__}")
    pairs = []
    for c in comparisons:
        if isinstance(c, (str, bytes)) or not isinstance(c, Sequence) or len(c) != 2:
            raise TypeError(f"{fn}: comparisons must hold (method, baseline) pairs, got {c!r:.60}")
        a, b = (A.string(fn, "comparisons", x) for x in c)
        absent = [x for x in (a, b) if x not in present]
        if absent:
            raise ValueError(f"{fn}: comparisons names {absent}, not a method of results (present: {present})")
        if a == b:
            raise ValueError(f"{fn}: comparisons pairs {a!r} with itself")
        pairs.append((a, b))
    return pairs


POSTERIOR_COLUMNS = ("target", "track", "method", "realization", "step", "posterior", "truth")


def _cells(rows: pd.DataFrame, params: M.Params) -> pd.DataFrame:
    """The evaluate stage's long results (probabilities per realization and step) reduced to one
    row of metrics per (target, track, setting, method), each group checked first."""
    fn = "evaluate_population"
    missing = [c for c in POSTERIOR_COLUMNS if c not in rows.columns]
    if missing:
        raise ValueError(f"{fn}: results has a 'posterior' column but lacks {missing} (a results table has "
                         f"{', '.join(POSTERIOR_COLUMNS)})")
    if "setting" not in rows.columns:
        rows = rows.assign(setting="default")
    out = []
    for (target, track, setting, m), g in rows.groupby(["target", "track", "setting", "method"], sort=True):
        where = f"results (target {target!r}, track {track!r}, setting {setting!r}, method {m!r})"
        if g.duplicated(["realization", "step"]).any():
            raise ValueError(f"{fn}: {where} has duplicated (realization, step) rows")
        g = g.sort_values(["realization", "step"])
        R, K = g["realization"].nunique(), g["step"].nunique()
        if len(g) != R * K:
            raise ValueError(f"{fn}: {where} has {len(g)} rows, not one per realization and step ({R} x {K})")
        try:
            post = np.stack([np.asarray(p, dtype=float) for p in g["posterior"]])
        except (TypeError, ValueError) as e:
            raise ValueError(f"{fn}: {where}: posterior must hold probability vectors of one length ({e})") from None
        if post.ndim != 2 or post.shape[1] < 2:
            raise ValueError(f"{fn}: {where}: posterior must hold probability vectors over >= 2 classes, "
                             f"got shape {post.shape}")
        if (post < 0).any():
            raise ValueError(f"{fn}: {where}: posterior holds negative probabilities")
        with np.errstate(divide="ignore"):
            bad = problem(np.log(post), (None, None))
        if bad is not None:
            raise ValueError(f"{fn}: {where}: posterior (as log probabilities) {bad}")
        truths = pd.unique(g["truth"])
        if len(truths) != 1:
            raise ValueError(f"{fn}: {where}: truth differs between rows ({list(truths)[:4]})")
        truth = A.integer(fn, f"{where}: truth", truths[0].item() if hasattr(truths[0], "item") else truths[0],
                          lo=0, hi=post.shape[1] - 1)
        out.append({"target": target, "track": track, "setting": setting, "method": m,
                    **M.posterior_metrics(post.reshape(R, K, -1), truth, params=params, is_log=False)})
    return pd.DataFrame(out)
