"""Calibration of a posterior: NLL, Brier score, confident errors and top-label ECE.

Posteriors come as log probabilities (..., C) with an integer ``truth`` (scalar or broadcastable
to the leading shape), as everywhere in ``pipeline.evaluation.metrics.spec``.

- ``nll``: -ln P(truth), read off the log posterior (never from a rounded probability, so a
  posterior that gives the truth 1e-3000 has NLL 6908, not infinity).
- ``brier``: the multi-class Brier score Σ_c (P(c) - 1[c = truth])² (0 = perfect, 2 = worst); the
  paper's MSDE is this divided by C.
- ``confident_error``: max_c P(c) >= threshold on a class that is not the truth.
- ECE: top-label expected calibration error with equal-width bins, the definition of
  torchmetrics' ``multiclass_calibration_error(norm="l1")``: confidence = max_c P(c), accuracy =
  argmax == truth, bin index = (number of boundaries linspace(0, 1, n_bins + 1) <= confidence) - 1,
  so a confidence of exactly 1.0 sits in a bin of its own (index n_bins);
  ECE = Σ_b (weight in b / total) |accuracy_b - confidence_b|.

``bin_sums`` returns, per bin, the weight, the weighted confidence sum and the weighted accuracy
sum: ECE is a function of sums, so a bootstrap can combine per-track sums (``ece_from_sums``)
instead of revisiting every posterior.
"""
from __future__ import annotations

import numpy as np

N_BINS = 15


def _lp(log_post) -> np.ndarray:
    lp = np.asarray(log_post, dtype=float)
    if lp.ndim < 1 or lp.shape[-1] < 1:
        raise ValueError(f"posteriors must have a class axis, got shape {lp.shape}")
    if np.any(np.isnan(lp)):
        raise ValueError("log posteriors contain NaN")
    return lp


def _truth(truth, lp: np.ndarray) -> np.ndarray:
    t = np.asarray(truth)
    if not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"truth must be integer class indices, got {t.dtype}")
    if np.any(t < 0) or np.any(t >= lp.shape[-1]):
        raise ValueError(f"truth index out of range for {lp.shape[-1]} classes")
    return np.broadcast_to(t, lp.shape[:-1])


def nll(log_post, truth) -> np.ndarray:
    """-ln P(truth) per posterior (..., C) -> (...)."""
    lp = _lp(log_post)
    t = _truth(truth, lp)
    return -np.take_along_axis(lp, t[..., None], axis=-1)[..., 0]


def brier(log_post, truth) -> np.ndarray:
    """Σ_c (P(c) - 1[c = truth])² per posterior."""
    lp = _lp(log_post)
    t = _truth(truth, lp)
    p = np.exp(lp)
    onehot = np.arange(lp.shape[-1]) == t[..., None]
    return np.sum((p - onehot) ** 2, axis=-1)


def top_label(log_post, truth) -> tuple[np.ndarray, np.ndarray]:
    """(confidence = max_c P(c), correct = argmax is the truth); ties go to the lowest index."""
    lp = _lp(log_post)
    t = _truth(truth, lp)
    return np.exp(lp.max(axis=-1)), np.argmax(lp, axis=-1) == t


def confident_error(log_post, truth, threshold: float) -> np.ndarray:
    """True where the posterior puts at least ``threshold`` on one wrong class."""
    if not 0.5 < threshold <= 1.0:
        raise ValueError(f"confident-error threshold must be in (0.5, 1], got {threshold}")
    conf, ok = top_label(log_post, truth)
    return (conf >= threshold) & ~ok


def bin_index(conf: np.ndarray, n_bins: int = N_BINS) -> np.ndarray:
    """Bin of each confidence: (number of boundaries <= conf) - 1, boundaries linspace(0, 1, n_bins + 1)."""
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    return np.clip(np.searchsorted(edges, np.asarray(conf, float), side="right") - 1, 0, n_bins)


def bin_sums(conf, correct, weights=None, n_bins: int = N_BINS) -> np.ndarray:
    """(3, n_bins + 1): per bin the total weight, Σ w·confidence and Σ w·accuracy."""
    conf = np.asarray(conf, float).ravel()
    acc = np.asarray(correct, float).ravel()
    w = np.ones_like(conf) if weights is None else np.broadcast_to(np.asarray(weights, float), conf.shape).ravel()
    b = bin_index(conf, n_bins)
    out = np.zeros((3, n_bins + 1))
    np.add.at(out[0], b, w)
    np.add.at(out[1], b, w * conf)
    np.add.at(out[2], b, w * acc)
    return out


def ece_from_sums(sums: np.ndarray) -> np.ndarray:
    """ECE of bin sums (..., 3, n_bins + 1): Σ_b |Σ w·acc - Σ w·conf| / Σ w (NaN without weight)."""
    s = np.asarray(sums, float)
    total = s[..., 0, :].sum(axis=-1)
    gap = np.abs(s[..., 2, :] - s[..., 1, :]).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, gap / np.where(total > 0, total, 1.0), np.nan)


def ece(conf, correct, weights=None, n_bins: int = N_BINS) -> float:
    """Top-label ECE of confidences and correctness flags (optionally weighted)."""
    return float(ece_from_sums(bin_sums(conf, correct, weights, n_bins)))


def reliability(sums: np.ndarray) -> dict[str, list]:
    """The reliability diagram of bin sums (3, n_bins + 1): per bin its edges, share of the weight,
    mean confidence and accuracy (None for an empty bin). The last bin holds confidence 1.0 only."""
    s = np.asarray(sums, float)
    nb = s.shape[-1] - 1
    edges = np.linspace(0.0, 1.0, nb + 1)
    total = s[0].sum()
    out = {"lower": [], "upper": [], "share": [], "confidence": [], "accuracy": []}
    for b in range(nb + 1):
        w = s[0, b]
        out["lower"].append(float(edges[b]) if b < nb else 1.0)
        out["upper"].append(float(edges[b + 1]) if b < nb else 1.0)
        out["share"].append(float(w / total) if total > 0 else None)
        out["confidence"].append(float(s[1, b] / w) if w > 0 else None)
        out["accuracy"].append(float(s[2, b] / w) if w > 0 else None)
    return out


def cell_calibration(log_post, truth, threshold: float) -> dict[str, float]:
    """A cell's calibration scalars over its realizations (R, K, C): means of NLL, Brier and the
    confident-error indicator at the final step and over all steps."""
    lp = _lp(log_post)
    n, b, e = nll(lp, truth), brier(lp, truth), confident_error(lp, truth, threshold)
    return {"nll_final": float(n[..., -1].mean()), "nll_overall": float(n.mean()),
            "brier_final": float(b[..., -1].mean()), "brier_overall": float(b.mean()),
            "confident_error_final": float(e[..., -1].mean()), "confident_error_overall": float(e.mean())}
