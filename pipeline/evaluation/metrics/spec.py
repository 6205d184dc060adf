"""The metric specification: every classification metric of the paper's §5.1, computed here only.

Two levels, each a registry where adding a metric is one entry (``register_metric``, public as
``vf.register_metric``, or an entry point of the group ``viewfuse.metrics``):

- ``STEP_COLUMNS``: per-step quantities of one posterior (..., C) against the truth, the columns of
  every results table (``pipeline.evaluation.metrics.results``):
  ``p_truth`` P(c_gt | H); ``log10_mgr`` log10(max_c P(c) / P(c_gt)) (0 when the truth is the
  most likely class; the only MGR base anywhere); ``msde`` (1/C) Σ_c (P(c|H) - 1[c = c_gt])²
  (paper Eq. 44; the multi-class Brier score is C · MSDE, the same quantity, so it is not a metric
  of its own); ``correct`` argmax = truth (ties go to the lowest class index, as ``numpy.argmax``).
- ``METRICS``: what a cell, a track table or a simulation scenario reports: a ``Metric`` reduces
  per-step columns of realizations × steps (R, K) to one number, with its labels, direction,
  bounds and how cells pool (``pool``: the mean over targets, or the median over targets for the
  unbounded log10 MGR and NLL; ``pipeline.evaluation.statistics.engine`` pools by it, so the number
  shown, its CI and its verdict are one statistic). ``compute`` applies every metric at once,
  vectorized over leading axes (bootstrap resamples), with its parameters (``Params``: the
  confident-error threshold and the ECE bins) from the config, never a built-in value.

Infinities: a truth probability of exactly 0 gives ``log10_mgr = +inf`` (from log posteriors it
stays finite). ``percentile`` treats +inf as a value above every other: a percentile that
interpolates toward it is +inf (one rule for every caller). Means propagate +inf. JSON writes
+inf as null (``pipeline.infra.cache.write_json``).

Posteriors are arrays (..., C), probabilities or, with ``is_log=True``, log probabilities;
``truth`` is a class index (an int, or an integer array broadcastable to the leading shape).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.infra.registry import Registry, caller_module
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.evaluation import ECE_BINS
from pipeline.infra import extension as X
from pipeline.infra.extension import ExtensionError, raise_problems

# the per-step quantities and the one percentile live in .steps; public here as before
from pipeline.evaluation.metrics.steps import (  # noqa: F401
    LN10, STEP_COLUMNS, confidence, correct, log10_mgr, log_mgr, msde, nll, percentile, prob_truth, step_values)


# -- aggregate metrics -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Params:
    """What some metrics need beyond the posteriors, from the config (``evaluate.confident_threshold``
    and ``evaluate.ece_bins``, or ``simulate.confident_threshold``); no metric has a built-in value."""
    confident_threshold: float
    ece_bins: int

    def __post_init__(self):
        if not 0.0 < float(self.confident_threshold) <= 1.0:
            raise ValueError(f"confident-error threshold must be in (0, 1], got {self.confident_threshold!r}")
        if int(self.ece_bins) < 2:
            raise ValueError(f"ece_bins must be at least 2, got {self.ece_bins!r}")

    @classmethod
    def of(cls, section) -> Params:
        """From a config section with ``confident_threshold`` (and ``ece_bins``: the evaluate
        section; the simulate section has no ECE and takes the evaluate default, ``ECE_BINS``)."""

        bins = getattr(section, "ece_bins", ECE_BINS)
        return cls(float(section.confident_threshold), int(bins))


def mean_of(x: np.ndarray, params: Params | None = None) -> np.ndarray:
    return x.mean(axis=-1)


def percentile_of(q: float) -> Callable[..., np.ndarray]:
    def reduce(x: np.ndarray, params: Params | None = None) -> np.ndarray:
        return percentile(x, q, axis=-1)
    reduce.__name__ = f"percentile_{q:g}"
    return reduce


@dataclass(frozen=True)
class Metric:
    """One reported metric: ``reduce`` maps the values of ``column`` over realizations (final
    step) or over realizations × steps (all steps), flattened on the last axis, to one number.
    A metric of several per-step columns (a calibration error needs confidence and correctness)
    names them as a tuple; ``reduce`` then gets one array per column, in that order.
    ``reduce`` also gets the run's ``Params``. ``best``/``worst`` are the attainable extremes
    (None: unbounded that way); cells where both methods of a comparison sit at one cannot tell
    them apart. Targets pool by ``pool``: "mean" or "median" (over targets of the target means;
    for metrics one target can move without bound)."""
    label: str                       # for sentences and captions
    short: str                       # for table headers
    higher_is_better: bool
    column: str | tuple[str, ...]    # ``STEP_COLUMNS`` key(s)
    steps: str                       # "final" | "all"
    reduce: Callable[..., np.ndarray]
    best: float | None = None
    worst: float | None = None
    pool: str = "mean"               # over targets: "mean" | "median" (settings and tracks: always the mean)
    key: str = ""                    # the identifying attribute (summary.json's key); set by register_metric
    color: str = "#555555"           # where a figure draws it
    note: str = ""                   # one line on what it measures

    @property
    def bounded(self) -> bool:
        return self.best is not None and self.worst is not None


ENTRY_POINT_GROUP = "viewfuse.metrics"


def problems(metric) -> list[str]:
    """Every breach of the metric contract ``metric`` declares (empty: none): an identifier key
    (not a pooled metric's), text labels, known per-step columns, ``steps`` and ``pool`` among
    the choices, a colour, and ``reduce`` callable as ``reduce(x, params=)`` (one array per column)."""

    if not isinstance(metric, Metric):
        return [f"{metric!r:.60} is not a Metric"]
    key, out = metric.key, []
    if not isinstance(key, str) or not key.isidentifier() or key in POOLED_METRICS:
        out.append(f"metric key {key!r:.60}: an identifier, not one of {sorted(POOLED_METRICS)}")
    for attr in ("label", "short"):
        out.append(X.text_problem(attr, getattr(metric, attr), empty=False))
    out.append(X.text_problem("note", metric.note))
    out.append(X.color_problem(metric.color))
    cols = (metric.column,) if isinstance(metric.column, str) else tuple(metric.column)
    bad = [c for c in cols if c not in STEP_COLUMNS]
    if bad:
        out.append(f"column(s) {bad} not in {sorted(STEP_COLUMNS)}")
    if metric.steps not in ("final", "all"):
        out.append(f"steps {metric.steps!r} not 'final'/'all'")
    if metric.pool not in POOLS:
        out.append(f"pool {metric.pool!r} not in {POOLS}")
    call = f"reduce({', '.join(['x'] * len(cols))}, params=Params)"
    out.append(X.signature_problem(metric.reduce, "reduce", call, *([None] * len(cols)), params=None))
    return [p for p in out if p]


def register_metric(key: str | Metric, metric: Metric | None = None, *, module: str | None = None) -> Metric:
    """Add a metric (after the built-ins; a key registered twice is an error): every results
    table, cell, population summary and simulation scenario then reports it. One spelling:
    ``register_metric(Metric(..., key="mine"))`` (``vf.register``); ``register_metric(key, metric)``
    is the older one, kept. ``module``: where it is defined (default: the caller's module), whose
    source enters the evaluate and simulate stages' cache key when it is not this module. Every
    breach of the contract (``problems``) is one ``ExtensionError`` naming the metric."""
    import dataclasses


    if metric is None:
        key, metric = getattr(key, "key", ""), key
    if isinstance(metric, Metric) and metric.key != key:
        metric = dataclasses.replace(metric, key=key)
    raise_problems("metric", key, "register", problems(metric))
    old = METRICS.peek(key)
    if old is not None and old != metric:
        raise ExtensionError.of("metric", key, "register",
                                f"registered twice ({METRICS.module_of(key)}, {module or caller_module()})")
    return METRICS.add(key, metric, module=module or caller_module(), replace=True)


def unregister_metric(key: str) -> None:
    METRICS.remove(key)


def _adopt(name: str, obj, module: str) -> None:
    if not isinstance(obj, Metric):
        raise TypeError(f"entry point {name!r} of {ENTRY_POINT_GROUP!r} names {obj!r}: not a module or a Metric")
    register_metric(name, obj, module=module)


# key -> Metric: the built-ins below first, in this order, then the registered ones (``register_metric``,
# the entry points of ``viewfuse.metrics``) in registration order.
METRICS: Registry[Metric] = Registry("metric", ENTRY_POINT_GROUP, __name__, static=(__name__,), adopt=_adopt)
_BUILTIN = {
    "correct_final": Metric("correct ratio, final step", "correct, final", True, "correct", "final", mean_of,
                            best=1.0, worst=0.0),
    "correct_overall": Metric("correct ratio, all steps", "correct, all steps", True, "correct", "all", mean_of,
                              best=1.0, worst=0.0),
    "prob_truth_final": Metric("P(truth), final step", "P(truth), final", True, "p_truth", "final", mean_of,
                               best=1.0, worst=0.0),
    "msde_final": Metric("MSDE, final step", "MSDE, final", False, "msde", "final", mean_of, best=0.0),
    "msde_overall": Metric("MSDE, all steps", "MSDE, all steps", False, "msde", "all", mean_of, best=0.0),
    "log10_mgr75_final": Metric("log10 MGR 75th percentile, final step", "log10 MGR 75%, final", False,
                                "log10_mgr", "final", percentile_of(75), best=0.0, pool="median"),
    "log10_mgr95_final": Metric("log10 MGR 95th percentile, final step", "log10 MGR 95%, final", False,
                                "log10_mgr", "final", percentile_of(95), best=0.0, pool="median"),
    "log10_mgr75_overall": Metric("log10 MGR 75th percentile, all steps", "log10 MGR 75%, all steps", False,
                                  "log10_mgr", "all", percentile_of(75), best=0.0, pool="median"),
    "log10_mgr95_overall": Metric("log10 MGR 95th percentile, all steps", "log10 MGR 95%, all steps", False,
                                  "log10_mgr", "all", percentile_of(95), best=0.0, pool="median"),
    # Calibration (docs/design.md §8): the confident-error rate at the run's threshold (``Params``).
    "nll_final": Metric("NLL of the truth, final step", "NLL, final", False, "nll", "final", mean_of, best=0.0,
                        pool="median"),
    "nll_overall": Metric("NLL of the truth, all steps", "NLL, all steps", False, "nll", "all", mean_of, best=0.0,
                          pool="median"),
    "confident_error_final": Metric("confident-error rate, final step",
                                    "confident errors, final", False, ("confidence", "correct"), "final",
                                    lambda c, ok, params: confident_rate(c, ok, params), best=0.0, worst=1.0),
    # The paper's §5.5.2 failure (Fig. 17): a wrong class at least 10 times as probable as the truth
    # at the last step, i.e. log10 MGR >= 1 (ln MGR >= ln 10 on the paper's scale).
    "wrong10_final": Metric("share with a wrong class ≥ 10× the truth (log10 MGR ≥ 1), final step",
                            "wrong ≥ 10× truth, final", False, "log10_mgr", "final",
                            lambda x, params=None: wrong_at_least(x, TEN_TIMES), best=0.0, worst=1.0),
    "confident_error_overall": Metric("confident-error rate, all steps",
                                      "confident errors, all steps", False, ("confidence", "correct"), "all",
                                      lambda c, ok, params: confident_rate(c, ok, params), best=0.0, worst=1.0),
}
POOLS = ("mean", "median")


TEN_TIMES = 1.0   # log10 of the paper's "about 10 times the correct class's" probability (§5.5.2)
# log10_mgr is ln(ratio) / ln 10: a ratio of exactly 10 can land a few ulps under 1.0, so the test
# allows that rounding (1e-12 in log10 is a ratio 10 (1 - 2.3e-12))
_ULPS = 1e-12


def wrong_at_least(log10_mgr: np.ndarray, decades: float) -> np.ndarray:
    """Share (last axis) of posteriors whose most likely wrong class is at least 10^``decades`` times
    the truth (log10 MGR >= decades; the truth on top gives 0, never counted for decades > 0)."""
    return (np.asarray(log10_mgr) >= float(decades) - _ULPS).mean(axis=-1)


def confident_mask(conf: np.ndarray, ok: np.ndarray, threshold: float) -> np.ndarray:
    """The one confident-error rule: top-label confidence >= ``threshold`` and the top label wrong."""
    t = float(threshold)
    if not 0.0 < t <= 1.0:
        raise ValueError(f"confident-error threshold must be in (0, 1], got {threshold!r}")
    return (np.asarray(conf) >= t) & (np.asarray(ok) < 0.5)


def confident_rate(conf: np.ndarray, ok: np.ndarray, params: Params) -> np.ndarray:
    """Share (last axis) of posteriors that are confident errors at ``params.confident_threshold``."""
    return confident_mask(conf, ok, params.confident_threshold).mean(axis=-1)
MGR_AXIS_LABEL = "log10 MGR = log10(max_c P(c) / P(truth))"


# Metrics of the pooled posteriors rather than of one cell (computed by
# ``pipeline.evaluation.metrics.calibration``: ECE is a function of bin sums, so it cannot be averaged over
# cells): key -> (label, short label); lower is better for each.
POOLED_METRICS = {
    "ece_final": ("top-label ECE, final step", "ECE, final"),
    "ece_overall": ("top-label ECE, all steps", "ECE, all steps"),
}
for _key, _metric in _BUILTIN.items():
    register_metric(_key, _metric)


def metric_label(key: str, short: bool = False) -> str:
    """A metric's label (``short`` for table headers); an unknown key is shown as itself."""
    m = METRICS.get(key)
    if m is None:
        return POOLED_METRICS[key][1 if short else 0] if key in POOLED_METRICS else key
    return m.short if short else m.label


def higher_is_better(key: str) -> bool:
    """The metric's direction; an unknown key (a newer summary) reads as higher-is-better."""
    if key in POOLED_METRICS:
        return False
    m = METRICS.get(key)
    return True if m is None else m.higher_is_better


def pool_of(key: str) -> str:
    """How targets pool a metric: ``Metric.pool``; a pooled metric (ECE) is one statistic of the
    pooled posteriors; an unknown key (a newer summary) by the mean."""
    if key in POOLED_METRICS:
        return "pooled posteriors"
    m = METRICS.get(key)
    return m.pool if m is not None else "mean"


def compute(values: Mapping[str, np.ndarray], keys: Sequence[str] | None = None, *,
            params: Params) -> dict[str, np.ndarray]:
    """Metrics of per-step values (..., R, K) per column (realizations × steps): arrays (...)."""
    out = {}
    for k in METRICS if keys is None else keys:
        m = METRICS[k]
        cols = (m.column,) if isinstance(m.column, str) else m.column
        if keys is None and not all(c in values for c in cols):
            continue  # a table written before the column existed (e.g. nll, confidence)
        xs = []
        for c in cols:
            x = np.asarray(values[c])
            xs.append((x[..., -1] if m.steps == "final" else x.reshape(*x.shape[:-2], -1)).astype(float))
        out[k] = m.reduce(*xs, params=params)
    return out


def scalars(values: Mapping[str, np.ndarray], keys: Sequence[str] | None = None, *,
            params: Params) -> dict[str, float]:
    """``compute`` for one set of (R, K) values: plain floats."""
    return {k: float(v) for k, v in compute(values, keys, params=params).items()}


def posterior_metrics(post, truth, *, params: Params, is_log: bool = False) -> dict[str, float]:
    """Every metric of posteriors over realizations × steps (R, K, C)."""
    return scalars(step_values(post, truth, is_log=is_log), params=params)


def matrices(df, columns: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """(R, K) matrices, realizations × steps (NaN where absent), of one group of long result rows
    (one method of one setting or scenario) for each per-step column."""
    import pandas as pd

    r_codes, r_vals = pd.factorize(df["realization"], sort=True)
    k_codes, k_vals = pd.factorize(df["step"], sort=True)
    out = {}
    for col in STEP_COLUMNS if columns is None else columns:
        if columns is None and col not in df:
            continue  # a table written before the column existed
        m = np.full((len(r_vals), len(k_vals)), np.nan)
        m[r_codes, k_codes] = df[col].to_numpy(float)
        out[col] = m
    return out


# exp() of a log10 above this overflows float64; such an MGR is kept only as log10.
_LOG10_MAX = float(np.log10(np.finfo(float).max))


def with_mgr_ratios(row: Mapping[str, float]) -> dict[str, float | None]:
    """``row`` plus, beside each ``log10_mgr<q>_<where>``, the ratio ``mgr<q>_<where>`` (None where
    it overflows float64); an infinite log10 becomes None (JSON has no infinity)."""
    out: dict[str, float | None] = {}
    for k, v in row.items():
        if k.startswith("log10_mgr"):
            v = float(v)
            ratio = v if np.isnan(v) else float(10.0 ** v) if v < _LOG10_MAX else None
            out[k.removeprefix("log10_")] = ratio
            out[k] = v if not np.isinf(v) else None
        else:
            out[k] = v
    return out


def confident_errors(log_post, truth, threshold: float) -> np.ndarray:
    """Per posterior (..., C) of log probabilities: ``confident_mask`` of its top-label confidence
    and correctness (the argmax ``correct`` uses, ties to the lowest index). Log posteriors are
    renormalised first, so unnormalised log weights give the same answer."""
    lp = np.asarray(log_post, dtype=float)
    if np.any(np.isnan(lp)):
        raise ValueError("posteriors contain NaN")
    top = lp.max(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        lse = top[..., 0] + np.log(np.sum(np.exp(lp - top), axis=-1))
    return confident_mask(np.exp(top[..., 0] - lse), correct(lp, truth), threshold)


def confident_error_rate(log_post, truth, threshold: float, axis=None) -> np.ndarray | float:
    """Share of posteriors that are confident errors (``confident_errors``), averaged over
    ``axis`` (None: all posteriors). The evaluate and simulate stages both use this definition."""
    e = confident_errors(log_post, truth, threshold)
    return float(e.mean()) if axis is None else e.mean(axis=axis)


def check_primary(keys) -> None:
    """``evaluate.primary_metrics`` must name metrics of the spec (or the pooled ECE), each once."""

    bad = [k for k in keys if k not in METRICS and k not in POOLED_METRICS]
    dup = sorted({k for k in keys if list(keys).count(k) > 1})
    if bad or dup or not keys:
        what = ("unknown metric(s) " + ", ".join(bad) if bad else
                "lists " + ", ".join(dup) + " more than once" if dup else "empty")
        raise ConfigError(f"config 'evaluate.primary_metrics' = {list(keys)!r}: {what}"
                          f" (known: {', '.join([*METRICS, *POOLED_METRICS])})")

