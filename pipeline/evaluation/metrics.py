"""Classification metrics of the paper's §5.1 over posteriors after every step.

Posteriors are arrays (..., C) (probabilities, or log probabilities with ``is_log=True``); ``truth``
is the ground-truth class index (an int, or an integer array broadcastable to the leading shape).
- ``prob_truth``: P(c_gt | H).
- ``msde``: (1/C) Σ_c (P(c|H) - 1[c = c_gt])² (paper Eq. 44).
- ``log_mgr``: ln(max_c P(c) / P(c_gt)); 0 when the truth is the most likely class.
- ``correct``: argmax = truth (ties go to the lowest class index, as ``numpy.argmax``);
  ``correct_ratio`` gives the final (last step) and overall (all steps) ratios.
"""
from __future__ import annotations

import numpy as np


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
    """ln(max_c P(c) / P(c_gt)) >= 0. From log posteriors it stays finite where probabilities
    underflow; from probabilities a zero P(c_gt) gives +inf."""
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


def correct(post, truth, *, is_log: bool = False) -> np.ndarray:
    p = np.asarray(post, dtype=float)  # argmax is the same in log space
    if np.any(np.isnan(p)):
        raise ValueError("posteriors contain NaN")
    return np.argmax(p, axis=-1) == _truth(truth, p)


def correct_ratio(post_track, truth, *, is_log: bool = False) -> tuple[float, float]:
    """(final, overall): share correct at the last step, and over all steps, of posteriors
    (..., K, C) (leading axes = episodes/realizations)."""
    ok = correct(post_track, truth if np.ndim(truth) == 0 else np.asarray(truth)[..., None], is_log=is_log)
    return float(np.mean(ok[..., -1])), float(np.mean(ok))


def percentile(x, q) -> np.ndarray:
    """Percentile (linear interpolation) that treats +inf as a value, not as NaN."""
    x = np.asarray(x, dtype=float).ravel()
    if x.size == 0:
        return np.full(np.shape(q), np.nan)
    big = np.finfo(float).max / 4
    out = np.percentile(np.where(np.isinf(x), big, x), q)
    return np.where(out >= big, np.inf, out)


def track_metrics(post_track, truth, *, is_log: bool = False) -> dict[str, np.ndarray]:
    """Per step metrics of posteriors (..., K, C): arrays (..., K) for prob_truth, msde, log_mgr,
    correct."""
    t = truth if np.ndim(truth) == 0 else np.asarray(truth)[..., None]
    return {"prob_truth": prob_truth(post_track, t, is_log=is_log), "msde": msde(post_track, t, is_log=is_log),
            "log_mgr": log_mgr(post_track, t, is_log=is_log), "correct": correct(post_track, t, is_log=is_log)}


def summary_row(post_track, truth, *, is_log: bool = False) -> dict[str, float]:
    """Flat scalars over realizations (R, K, C): the paper's Tables 1-2 (correct ratio and log MGR
    75%/95% percentiles, final and overall) plus mean P(truth) and MSDE, final and over all steps."""
    m = track_metrics(post_track, truth, is_log=is_log)
    fin, ovr = correct_ratio(post_track, truth, is_log=is_log)
    return {
        "correct_final": fin, "correct_overall": ovr,
        "log_mgr_p75_final": float(percentile(m["log_mgr"][..., -1], 75)),
        "log_mgr_p95_final": float(percentile(m["log_mgr"][..., -1], 95)),
        "log_mgr_p75_overall": float(percentile(m["log_mgr"], 75)),
        "log_mgr_p95_overall": float(percentile(m["log_mgr"], 95)),
        "prob_truth_final": float(np.mean(m["prob_truth"][..., -1])),
        "prob_truth_overall": float(np.mean(m["prob_truth"])),
        "msde_final": float(np.mean(m["msde"][..., -1])), "msde_overall": float(np.mean(m["msde"])),
    }


# exp() of a natural log above this overflows float64; such an MGR is kept only as log10.
_LN_MAX = float(np.log(np.finfo(float).max))


def mgr_fields(log_mgr: float, suffix: str) -> dict[str, float | None]:
    """``mgr<suffix>`` as a ratio (None where it overflows float64) and ``log10_mgr<suffix>``.

    Model Based can be wrong with a truth probability of 1e-3000: that is still a number in log
    space, and JSON has no infinity, so the log10 is always written and the ratio when it fits.
    """
    lm = float(log_mgr)
    if np.isnan(lm):  # no values: stays "not available"
        return {f"mgr{suffix}": lm, f"log10_mgr{suffix}": lm}
    return {f"mgr{suffix}": float(np.exp(lm)) if lm < _LN_MAX else None,
            f"log10_mgr{suffix}": lm / float(np.log(10.0)) if np.isfinite(lm) else None}


def mgr_percentile_fields(log_mgr_final, log_mgr_all) -> dict[str, float | None]:
    """The paper's table MGR entries: 75th/95th percentiles of log MGR at the final step and over
    all steps, each as ``mgr<q>_<where>`` and ``log10_mgr<q>_<where>`` (see ``mgr_fields``)."""
    out: dict[str, float | None] = {}
    for where, x in (("final", log_mgr_final), ("overall", log_mgr_all)):
        for q in (75, 95):
            out.update(mgr_fields(float(percentile(x, q)), f"{q}_{where}"))
    return out


def confident_errors(log_post, truth, threshold: float) -> np.ndarray:
    """Per posterior (..., C) of log probabilities: True where the most probable class is wrong
    and holds P >= ``threshold`` ("max P >= 0.99 on a wrong class" at 0.99). The argmax is the
    one ``correct`` uses (ties to the lowest index); log posteriors are renormalised first, so
    unnormalised log weights give the same answer."""
    t = float(threshold)
    if not 0.0 < t <= 1.0:
        raise ValueError(f"confident-error threshold must be in (0, 1], got {threshold!r}")
    lp = np.asarray(log_post, dtype=float)
    if np.any(np.isnan(lp)):
        raise ValueError("posteriors contain NaN")
    top = lp.max(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        lse = top[..., 0] + np.log(np.sum(np.exp(lp - top), axis=-1))
    wrong = ~correct(lp, truth)
    return wrong & (top[..., 0] - lse >= np.log(t))


def confident_error_rate(log_post, truth, threshold: float, axis=None) -> np.ndarray | float:
    """Share of posteriors that are confident errors (``confident_errors``), averaged over
    ``axis`` (None: all posteriors). The evaluate and simulate stages both use this definition."""
    e = confident_errors(log_post, truth, threshold)
    return float(e.mean()) if axis is None else e.mean(axis=axis)
