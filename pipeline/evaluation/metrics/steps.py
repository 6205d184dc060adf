"""Per-step quantities of one posterior against the truth (the ``STEP_COLUMNS`` of every results
table) and the one percentile with its infinity rule: the lowest level of the metric specification
(``pipeline.evaluation.metrics.spec``, which re-exports every name here and documents both).

Posteriors are arrays (..., C), probabilities or, with ``is_log=True``, log probabilities;
``truth`` is a class index (an int, or an integer array broadcastable to the leading shape).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

LN10 = float(np.log(10.0))


# -- per-step quantities ----------------------------------------------------------------------------
def _post(post, is_log: bool) -> np.ndarray:
    p = np.asarray(post, dtype=float)
    if p.ndim < 1 or p.shape[-1] < 1:
        raise ValueError(f"posteriors must have a class axis, got shape {p.shape}")
    if np.any(np.isnan(p)):
        raise ValueError("posteriors contain NaN")
    return np.exp(p) if is_log else p


def _truth(truth, p: np.ndarray) -> np.ndarray:
    t = np.asarray(truth)
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"truth must be integer class indices, got {t.dtype}")
    C = p.shape[-1]
    if np.any(t < 0) or np.any(t >= C):
        raise ValueError(f"truth index out of range for {C} classes: {np.unique(t).tolist()}")
    return np.broadcast_to(t, p.shape[:-1])


def prob_truth(post, truth, *, is_log: bool = False) -> np.ndarray:
    p = _post(post, is_log)
    t = _truth(truth, p)
    return np.take_along_axis(p, t[..., None], axis=-1)[..., 0]


def msde(post, truth, *, is_log: bool = False) -> np.ndarray:
    p = _post(post, is_log)
    t = _truth(truth, p)
    onehot = np.arange(p.shape[-1]) == t[..., None]
    return np.mean((p - onehot) ** 2, axis=-1)


def log_mgr(post, truth, *, is_log: bool = False) -> np.ndarray:
    """ln(max_c P(c) / P(c_gt)) >= 0, the natural log ``log10_mgr`` is derived from. From log
    posteriors it stays finite where probabilities underflow; from probabilities a zero P(c_gt)
    gives +inf."""
    lp = np.asarray(post, dtype=float)
    if not is_log:
        with np.errstate(divide="ignore"):
            lp = np.log(_post(lp, False))
    elif np.any(np.isnan(lp)):
        raise ValueError("posteriors contain NaN")
    t = _truth(truth, lp)
    lt = np.take_along_axis(lp, t[..., None], axis=-1)[..., 0]
    with np.errstate(invalid="ignore"):
        out = lp.max(axis=-1) - lt
    return np.where(np.isnan(out), np.inf, out)  # -inf - -inf: truth impossible and so is all else


def log10_mgr(post, truth, *, is_log: bool = False) -> np.ndarray:
    """log10(max_c P(c) / P(c_gt)): the MGR every table, figure and summary shows."""
    return log_mgr(post, truth, is_log=is_log) / LN10


def correct(post, truth, *, is_log: bool = False) -> np.ndarray:
    p = np.asarray(post, dtype=float)  # argmax is the same in log space
    if np.any(np.isnan(p)):
        raise ValueError("posteriors contain NaN")
    return np.argmax(p, axis=-1) == _truth(truth, p)


# Column name -> function (post, truth, is_log=) -> per-step values (...). Order = column order.
def nll(post, truth, *, is_log: bool = False) -> np.ndarray:
    """-ln P(c_gt): from log posteriors read off directly (finite where the probability underflows)."""
    if is_log:
        lp = np.asarray(post, dtype=float)
        return -np.take_along_axis(lp, _truth(truth, lp)[..., None], axis=-1)[..., 0]
    with np.errstate(divide="ignore"):
        return -np.log(prob_truth(post, truth))


def confidence(post, truth, *, is_log: bool = False) -> np.ndarray:
    """Top-label confidence max_c P(c)."""
    return _post(post, is_log).max(axis=-1)


STEP_COLUMNS: dict[str, Callable[..., np.ndarray]] = {
    "p_truth": prob_truth,
    "log10_mgr": log10_mgr,
    "msde": msde,
    "correct": correct,
    "nll": nll,
    "confidence": confidence,
}


def step_values(post, truth, *, is_log: bool = False) -> dict[str, np.ndarray]:
    """Every ``STEP_COLUMNS`` quantity of posteriors (..., C): arrays (...)."""
    return {k: f(post, truth, is_log=is_log) for k, f in STEP_COLUMNS.items()}


# -- the one percentile -----------------------------------------------------------------------------
_BIG = np.finfo(float).max / 4   # +-inf's stand-in: finite, so numpy interpolates instead of NaN
_INF_ABOVE = 1e300               # any interpolation weight on the stand-in lands beyond this


def percentile(x, q, axis: int | None = None) -> np.ndarray:
    """Linear-interpolation percentile (``numpy.percentile``) with the one infinity rule: +inf and
    -inf are values, and a result that interpolates toward an infinite entry is that infinity; a
    NaN entry makes its slice NaN. ``axis=None`` flattens (an empty input gives NaN). The
    statistics engine's interval is this percentile at 2.5 and 97.5."""
    x = np.asarray(x, dtype=float)
    if axis is None:
        x = x.ravel()
        if x.size == 0:
            return np.full(np.shape(q), np.nan)
    out = np.percentile(np.clip(x, -_BIG, _BIG), q, axis=-1 if axis is None else axis)
    return np.where(out > _INF_ABOVE, np.inf, np.where(out < -_INF_ABOVE, -np.inf, out))
