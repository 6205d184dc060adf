"""Top-label ECE and the reliability diagram: the calibration statistics that are not cell means.

NLL, the confident-error rate and MSDE (the Brier score / C) are metrics of the one specification
(``pipeline.evaluation.metrics.spec``: step columns ``nll``, ``confidence``, ``correct``, ``msde``);
this module only bins confidences. Posteriors come as log probabilities (..., C) with an integer
``truth`` (scalar or broadcastable to the leading shape).

ECE: top-label expected calibration error with equal-width bins (``evaluate.ece_bins``), the
definition of torchmetrics' ``multiclass_calibration_error(norm="l1")``: confidence = max_c P(c),
accuracy = argmax == truth, bin index = (number of boundaries linspace(0, 1, n_bins + 1) <=
confidence) - 1, so a confidence of exactly 1.0 sits in a bin of its own (index n_bins);
ECE = Σ_b (weight in b / total) |accuracy_b - confidence_b|.

``bin_sums`` returns, per bin, the weight, the weighted confidence sum and the weighted accuracy
sum: ECE is a function of sums, so a bootstrap can combine per-track sums (``ece_from_sums``)
instead of revisiting every posterior.
"""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.metrics.spec import confidence, correct

N_BINS = 15


def top_label(log_post, truth) -> tuple[np.ndarray, np.ndarray]:
    """(confidence = max_c P(c), correct = argmax is the truth), the spec's step columns."""
    return confidence(log_post, truth, is_log=True), correct(log_post, truth, is_log=True)


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
