"""The numbers behind the simulation report's findings (paper §5.3): per scenario and method,
percentile-band widths, confident misclassifications and the inverse-view dip, MGR as log10."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics.labels import MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY, method_label
from pipeline.evaluation.metrics.spec import confident_errors, percentile
from reports.shared.numbers import fmt, percent, plain

OURS = WITH_UNCERTAINTY
OTHERS = (MODEL_BASED, SIMPLE_BAYES)
# "Confidently wrong": max P >= ``simulate.confident_threshold`` on a wrong class (the stage passes
# the configured value; no built-in one).


# -- numbers --------------------------------------------------------------------------------------------
def matrix(df: pd.DataFrame, column: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps (K,), values (R, K)) of one method's rows."""
    piv = df.pivot(index="realization", columns="step", values=column).sort_index(axis=1)
    return piv.columns.to_numpy(), piv.to_numpy(float)


def column_percentile(v: np.ndarray, q: float) -> np.ndarray:
    """Per-step (column) percentile of (R, K) values, +inf (underflowed P(truth)) kept as a value."""
    return percentile(v, q, axis=0)


def inverse_steps(ex: pd.DataFrame, scenario: str, truth: int) -> list[int]:
    """Steps where the truth's GP mean score vector (at the true pose) favours another class."""
    e = ex[ex["scenario"] == scenario]
    out = []
    for k, g in e.groupby("step"):
        means = np.array([m[truth] for m in g.sort_values("component")["class_mean"]])
        if int(np.argmax(means)) != truth:
            out.append(int(k))
    return out


def findings(df: pd.DataFrame, ex: pd.DataFrame, truth: int,
             posteriors: Mapping[str, Mapping[str, np.ndarray]], confident: float) -> dict[str, Any]:
    """Numbers behind the paper's qualitative findings, per scenario present; "confidently wrong"
    is ``metrics.confident_errors`` at ``confident`` on ``posteriors`` ({scenario: {method:
    (R, K, C)}}, the rows of ``df``). The stage writes them to summary.json; the page reads them."""
    out: dict[str, Any] = {"confident_threshold": confident}
    for scenario, g in df.groupby("scenario", sort=False):
        s: dict[str, Any] = {}
        for method, gm in g.groupby("method", sort=False):
            steps, pt = matrix(gm, "p_truth")
            _, lm = matrix(gm, "log10_mgr")
            with np.errstate(divide="ignore"):
                wrong_conf = confident_errors(np.log(posteriors[scenario][method]), truth, confident)
            q10, q25, q50, q75, q90 = percentile(pt, [10, 25, 50, 75, 90], axis=0)
            s[method] = {
                "ptruth_band_10_90_mean": float(np.mean(q90 - q10)),
                "ptruth_iqr_mean": float(np.mean(q75 - q25)),
                "ptruth_median_final": float(q50[-1]),
                "ptruth_median_min": float(q50.min()),
                "ptruth_median_argmin_step": int(steps[int(np.argmin(q50))]),
                "confident_wrong_final": float(wrong_conf[:, -1].mean()),
                "confident_wrong_any_step": float(wrong_conf.any(axis=1).mean()),
                "confident_wrong_overall": float(wrong_conf.mean()),
                "log10_mgr_p90_max": float(np.max(column_percentile(lm, 90))),
            }
        inv = inverse_steps(ex, scenario, truth)
        s["inverse_steps"] = inv
        if inv:
            first, last = inv[0], inv[-1]
            for method, gm in g.groupby("method", sort=False):
                steps, pt = matrix(gm, "p_truth")
                med = np.median(pt, axis=0)
                before = float(med[max(first - 1, 0)])
                window = med[first: min(last + 3, len(med))]
                s[method]["median_before_inverse"] = before
                s[method]["median_min_at_inverse"] = float(window.min())
                s[method]["median_drop_at_inverse"] = before - float(window.min())
                _, lm = matrix(gm, "log10_mgr")
                p90 = column_percentile(lm, 90)
                s[method]["log10_mgr_p90_before_inverse"] = float(p90[max(first - 1, 0)])
                s[method]["log10_mgr_p90_max_at_inverse"] = float(p90[first: min(last + 3, len(p90))].max())
        out[scenario] = s
    return out


def findings_text(found: dict[str, Any]) -> list[str]:
    """Plain-language checks of the paper's three qualitative findings, with the numbers."""
    lines = []
    conf = found["confident_threshold"]
    mu = found.get("model_uncertainty")
    if mu:
        w = {m: mu[m]["ptruth_band_10_90_mean"] for m in (OURS,) + OTHERS if m in mu}
        narrower = all(w[OURS] < w[m] for m in OTHERS if m in w)
        lines.append(
            f"Model uncertainty — P(truth) percentiles: mean 10–90% band width {fmt(w.get(OURS))} "
            f"(With Uncertainty; {'the narrowest' if narrower else 'not the narrowest'}) vs "
            + ", ".join(f"{fmt(w[m])} ({method_label(m, short=True)})" for m in OTHERS if m in w)
            + "; 90th percentile of log10 MGR at its worst step: "
            + ", ".join(f"{fmt(mu[m]['log10_mgr_p90_max'])} ({method_label(m, short=True)})"
                        for m in (OURS,) + OTHERS if m in mu)
            + f"; confidently wrong (max P ≥ {plain(conf)} on a wrong class) over all steps / at some step of a realization: "
            + ", ".join(f"{percent(mu[m]['confident_wrong_overall'], 1)} / "
                        f"{percent(mu[m]['confident_wrong_any_step'])} ({method_label(m, short=True)})"
                        for m in (OURS,) + OTHERS if m in mu) + ".")
        if mu.get("inverse_steps") and "simple_bayes" in mu:
            sb, inv = mu["simple_bayes"], mu["inverse_steps"]
            ours = mu.get(OURS, {})
            lines.append(
                f"Model uncertainty — Simple Bayes at the inverse view (steps {inv[0]}–{inv[-1]}, where the "
                f"truth looks like another class): its median P(truth) falls from "
                f"{fmt(sb['median_before_inverse'])} to {fmt(sb['median_min_at_inverse'])} "
                f"(drop {fmt(sb['median_drop_at_inverse'])}); With Uncertainty goes {fmt(ours.get('median_before_inverse'))}"
                f" → {fmt(ours.get('median_min_at_inverse'))}, Model Based "
                f"{fmt(mu.get('model_based', {}).get('median_before_inverse'))} → "
                f"{fmt(mu.get('model_based', {}).get('median_min_at_inverse'))}. The 90th "
                f"percentile of Simple Bayes' log10 MGR rises from {fmt(sb['log10_mgr_p90_before_inverse'])} to "
                f"{fmt(sb['log10_mgr_p90_max_at_inverse'])} there (With Uncertainty: "
                f"{fmt(ours.get('log10_mgr_p90_before_inverse'))} → "
                f"{fmt(ours.get('log10_mgr_p90_max_at_inverse'))}).")
    lb = found.get("localization_bias")
    if lb and "model_based" in lb:
        mb, ours = lb["model_based"], lb.get(OURS, {})
        lines.append(
            f"Localization bias — Model Based is confidently wrong (max P ≥ {plain(conf)} on a wrong class) in "
            f"{percent(mb['confident_wrong_any_step'])} of realizations at some step and "
            f"{percent(mb['confident_wrong_final'])} at the last step; its median P(truth) bottoms at "
            f"{fmt(mb['ptruth_median_min'])} (step {mb['ptruth_median_argmin_step']}). With Uncertainty: "
            f"{percent(ours.get('confident_wrong_any_step'))} / "
            f"{percent(ours.get('confident_wrong_final'))}, median P(truth) ≥ "
            f"{fmt(ours.get('ptruth_median_min'))}.")
    return lines
