"""Figures of the results: population (forest plot, per-target CIs) and the detailed track
(biased track, percentile bands, σ sensitivity, the track from above).

MGR is log10 everywhere (``pipeline.evaluation.metrics.spec.MGR_AXIS_LABEL``), drawn on a symmetric-log axis
(``reports.shared.figures.mgr_axis``: linear within ±1, logarithmic beyond) because the values span 0 to
1e5; every estimate that has a CI is drawn with its CI bar. A panel whose data are constant says so
on the panel instead of showing a bare flat line.
"""
from __future__ import annotations

import math

from typing import Any

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics.labels import comparison_key, method_color, method_label, ordered_methods, present_comparisons
from pipeline.evaluation.metrics.spec import MGR_AXIS_LABEL, higher_is_better, matrices, metric_label
from pipeline.infra.outputs import number
from reports.shared.records import varies_text
from reports.main.calibration import paired_value, pooled_value
from reports.shared.figures import (mgr_axis, mgr_scale_label, new_figure, new_subplots, percentile_bands, step_ticks,
                             wrap_label)
from reports.shared.numbers import fmt, plain
from reports.main.bottom_line import counts

FOREST_METRICS = ("correct_final", "prob_truth_final", "log10_mgr95_final")
PER_TARGET_METRICS = ("correct_final", "log10_mgr95_final")


def _ci_rows(ax, ys, entries, color: str, marker: str, label: str) -> None:
    """Points with horizontal 95 % CI bars; entries are contract dicts (value, ci_low, ci_high)."""
    v = np.array([number(e.get("value"), finite=True) for e in entries])
    lo = np.array([number(e.get("ci_low"), v[i], v[i], finite=True) for i, e in enumerate(entries)])
    hi = np.array([number(e.get("ci_high"), v[i], v[i], finite=True) for i, e in enumerate(entries)])
    ok = np.isfinite(v)
    err = np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)])
    ax.errorbar(v[ok], np.asarray(ys)[ok], xerr=err[:, ok], fmt=marker, color=color, ms=5, capsize=3,
                lw=1.3, label=label)


def fig_forest(pop: dict) -> Any:
    """Paired differences With Uncertainty − baseline per target and pooled, with 95 % CIs."""
    targets = list(pop.get("targets") or [])
    rows = targets + ["pooled (all targets)"]
    ppt, paired = pop.get("paired_per_target") or {}, pop.get("paired") or {}
    metrics = [m for m in FOREST_METRICS if m in (pop.get("metrics") or FOREST_METRICS)]
    keys = _comparison_keys(paired, ppt)
    fig, axes = new_subplots(1, len(metrics), w=min(1.6 + 3.0 * len(metrics), 10.8),
                             h=1.6 + max(0.55, 0.14 * (len(keys) + 1)) * len(rows), sharey=True)
    marks = ("o", "s", "D", "^")
    for ax, metric in zip(axes[0], metrics):
        drawn = []
        for i, key in enumerate(keys):
            m, _, base = key.partition("-")
            entries = [(ppt.get(key, {}).get(t, {}) or {}).get(metric, {}) for t in targets]
            entries.append(paired_value(pop, key, metric) or {})   # the statistic the verdict reads
            ys = np.arange(len(rows)) + (i - (len(keys) - 1) / 2) * 0.22
            _ci_rows(ax, ys, entries, method_color(base), marks[i % len(marks)],
                     f"{method_label(m, True)} − {method_label(base, True)}")
            drawn += [number(e.get(k), finite=True) for e in entries for k in ("value", "ci_low", "ci_high")]
        if "mgr" in metric:
            mgr_axis(ax, drawn, axis="x")
        ax.axvline(0.0, color="#444444", lw=1)
        ax.axhline(len(targets) - 0.5, color="#bbbbbb", lw=0.8)
        side = "right" if higher_is_better(metric) else "left"
        ax.set_title(f"{metric_label(metric)}\n(With Uncertainty better to the {side})", fontsize=9.5)
        ax.set_xlabel(mgr_scale_label("difference of log10 MGR") if "mgr" in metric else "difference")
    axes[0, 0].set_yticks(range(len(rows)))
    axes[0, 0].set_yticklabels(_row_labels(pop, targets))
    axes[0, 0].invert_yaxis()
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=max(min(len(keys), 3), 1),
               frameon=False)
    fig.suptitle(f"Paired differences per target, 95 % bootstrap CIs over tracks ({_pooled_over(pop)})")
    return fig


def _row_labels(pop: dict, targets: list[str]) -> list[str]:
    """Target names with their track count (a 1-track target's point has no CI bar: say why)."""
    n = counts(pop)["tracks_per_target"]
    lab = [wrap_label(t, 24) + (f"\n({n[t]} track{'s' if n[t] != 1 else ''}"
                                + (": no CI)" if n[t] == 1 else ")") if t in n else "") for t in targets]
    return lab + ["pooled (all targets)"]


def _comparison_keys(*maps: dict) -> list[str]:
    return [comparison_key(m, b) for m, b in present_comparisons({k for mp in maps for k in mp})]


def fig_per_target(pop: dict) -> Any:
    """Each method's value per target and pooled, with 95 % CIs."""
    targets = list(pop.get("targets") or [])
    rows = targets + ["pooled (all targets)"]
    per, pooled = pop.get("per_target") or {}, pop.get("pooled") or {}
    methods = ordered_methods(pop.get("methods") or pooled.keys())
    fig, axes = new_subplots(1, len(PER_TARGET_METRICS), w=2.0 + 3.6 * len(PER_TARGET_METRICS),
                             h=1.6 + 0.6 * len(rows), sharey=True)
    for ax, metric in zip(axes[0], PER_TARGET_METRICS):
        drawn: list[float] = []
        for i, m in enumerate(methods):
            entries = [((per.get(t) or {}).get(m) or {}).get(metric, {}) for t in targets]
            entries.append(pooled_value(pop, m, metric) or {})   # the pooled table's statistic
            ys = np.arange(len(rows)) + (i - (len(methods) - 1) / 2) * 0.2
            _ci_rows(ax, ys, entries, method_color(m), "o", method_label(m))
            if "mgr" in metric:
                drawn += [number(e.get(k), finite=True) for e in entries for k in ("value", "ci_low", "ci_high")]
        if "mgr" in metric:
            mgr_axis(ax, drawn, axis="x")
        ax.axhline(len(targets) - 0.5, color="#bbbbbb", lw=0.8)
        ax.set_title(metric_label(metric), fontsize=9.5)
        ax.set_xlabel(mgr_scale_label(MGR_AXIS_LABEL) if "mgr" in metric else metric_label(metric))
    axes[0, 0].set_yticks(range(len(rows)))
    axes[0, 0].set_yticklabels(_row_labels(pop, targets))
    axes[0, 0].invert_yaxis()
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=3, frameon=False)
    fig.suptitle(f"Per target and pooled, 95 % bootstrap CIs over tracks ({_pooled_over(pop)})")
    return fig


def decisive_step(df: pd.DataFrame) -> dict | None:
    """The view that moves P(truth) most on the biased track: the step k with the largest
    |P_k − P_(k−1)| (median over realizations) over the methods; None on a one-step track."""
    best = None
    for m in ordered_methods(df["method"].unique()):
        p = np.nanmedian(matrices(df[df["method"] == m])["p_truth"], axis=0)
        if p.size < 2:
            return None
        d = np.diff(p)
        k = int(np.nanargmax(np.abs(d)))
        if best is None or abs(d[k]) > abs(best["change"]):
            steps = np.sort(df["step"].unique())
            best = {"step": int(steps[k + 1]), "method": m, "change": float(d[k]), "before": float(p[k]),
                    "after": float(p[k + 1])}
    return best


def fig_biased(df: pd.DataFrame, n_classes: int, images: list[str] | None = None) -> Any:
    fig, ax = new_figure(6.4, 4.2)
    steps = np.sort(df["step"].unique())
    key = decisive_step(df)
    if key is not None:
        ax.axvspan(key["step"] - 0.5, key["step"] + 0.5, color="#f2d7a6", alpha=0.55, lw=0, zorder=0)
        img = images[key["step"]] if images and 0 <= key["step"] < len(images) else ""
        ax.annotate(f"view {key['step']}{' (' + img + ')' if img else ''} moves P(truth) most:\n"
                    f"{method_label(key['method'], True)} {fmt(key['before'])} → {fmt(key['after'])}",
                    xy=(key["step"], 1.02), xycoords=("data", "axes fraction"), ha="center", va="bottom",
                    fontsize=8.5, annotation_clip=False)
    for m in ordered_methods(df["method"].unique()):
        v = matrices(df[df["method"] == m])["p_truth"]
        if v.shape[0] == 1:
            ax.plot(steps, v[0], "-o", color=method_color(m), label=method_label(m), ms=4, lw=1.8)
        else:  # several realizations: median and 10–90 % range
            ax.plot(steps, np.nanmedian(v, 0), "-o", color=method_color(m), label=method_label(m) + " (median)",
                    ms=4, lw=1.8)
            ax.fill_between(steps, np.nanpercentile(v, 10, 0), np.nanpercentile(v, 90, 0), step="mid",
                            color=method_color(m), alpha=0.15, lw=0)
    if n_classes:
        ax.axhline(1 / n_classes, color="#777777", ls="--", lw=1, label=f"uniform (1/{n_classes})")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("track step k")
    ax.set_ylabel("P(ground-truth class | history)")
    step_ticks(ax, steps)
    # Outside the axes: a legend inside covered the curves (a drop at the last steps).
    handles, labels = ax.get_legend_handles_labels()
    # one column per ~320 px of width, so long method names never run past the canvas
    fig.legend(handles, [wrap_label(t, 40) for t in labels], loc="outside lower center",
               ncol=max(1, min(2, int(fig.get_figwidth() // 3.2))), frameon=False)
    return fig


BAND_COLUMNS = 3   # panels per row: four side by side printed their titles over each other


def fig_bands(df: pd.DataFrame, column: str, ylabel: str, title: str) -> tuple[Any, int]:
    """One panel per method (at most ``BAND_COLUMNS`` per row, so panel titles keep apart), shared
    y; returns (fig, number of +inf values drawn at the top)."""
    methods = ordered_methods(df["method"].unique())
    ncol = min(len(methods), BAND_COLUMNS)
    nrow = math.ceil(len(methods) / ncol)
    fig, axes = new_subplots(nrow, ncol, w=0.8 + 3.5 * ncol, h=0.6 + 3.0 * nrow, sharey=True)
    for ax in axes.flat[len(methods):]:
        ax.set_visible(False)
    axes = axes.reshape(1, -1)
    mats = {m: matrices(df[df["method"] == m])[column] for m in methods}
    steps = np.sort(df["step"].unique())
    finite = np.concatenate([v[np.isfinite(v)] for v in mats.values()] + [np.zeros(1)])
    cap = float(finite.max()) if finite.size else 1.0
    clipped = 0
    for ax, m in zip(axes[0], methods):
        v = mats[m]
        bad = np.isposinf(v)
        clipped += int(bad.sum())
        percentile_bands(ax, steps, np.where(bad, cap, v), method_color(m))
        note = constant_note(v)
        # In the title, not on the data: a flat band is a finding, and a box would hide the line.
        ax.set_title(f"{wrap_label(method_label(m), 34)}\nR = {v.shape[0]} realizations" + (f"\n{note}" if note else ""),
                     fontsize=9.5 if not note else 8.5)
        ax.set_xlabel("track step k")
        step_ticks(ax, steps)
    for r in range(nrow):
        axes[0, r * ncol].set_ylabel(ylabel if column == "p_truth" else mgr_scale_label(ylabel))
    if column == "p_truth":
        axes[0, 0].set_ylim(-0.02, 1.02)
    else:
        mgr_axis(axes[0, 0], finite, axis="y")
    fig.suptitle(title)
    return fig, clipped


def constant_note(v: np.ndarray) -> str:
    """Words for a panel whose band has no width ('' when the realizations differ somewhere)."""
    v = np.asarray(v, float)
    if v.ndim != 2 or v.shape[0] < 2:
        return ""
    spread = np.nanmax(v, axis=0) - np.nanmin(v, axis=0)
    if np.all(np.nan_to_num(spread, nan=0.0) < 1e-12):
        flat = np.nanmax(v) - np.nanmin(v) < 1e-12
        return ("all identical: the localization noise\ndoes not reach this method"
                + (f" (constant {fmt(np.nanmax(v))})" if flat else ""))
    return ""


def _ci_line(ax, x, ests, color: str, label: str, ls: str = "-") -> int:
    """Line with CI error bars through Estimates; an infinite upper bound is drawn to the axis top
    (returned count) so the bar still says 'unbounded'."""
    # a method missing from a setting has no estimate there: a gap, not a crash
    v = np.array([number(getattr(e, "value", None), finite=True) for e in ests])
    lo = np.array([number(getattr(e, "low", None), v[i], v[i], finite=True) for i, e in enumerate(ests)])
    hi_raw = np.array([np.inf if getattr(e, "high", None) is not None and np.isposinf(float(e.high))
                       else number(getattr(e, "high", None), v[i], v[i], finite=True)
                       for i, e in enumerate(ests)])
    top = np.nanmax(np.concatenate([v, lo, hi_raw[np.isfinite(hi_raw)], [0.0]]))
    hi = np.where(np.isinf(hi_raw), top * 1.05 + 0.05, hi_raw)
    err = np.vstack([np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)])
    ax.errorbar(x, v, yerr=err, fmt="o" + ls, color=color, ms=4, capsize=3, lw=1.5, label=label)
    return int(np.isinf(hi_raw).sum())


def fig_sensitivity(summ: dict) -> Any:
    """Correct ratio and log10 MGR95 (final step) vs σ, each with its 95 % CI over realizations."""
    fig, axes = new_subplots(1, 2, w=10.0, h=4.4)
    settings = sorted(summ, key=lambda s: summ[s]["sigma_m"])
    sig = np.array([summ[s]["sigma_m"] for s in settings])
    methods = ordered_methods({m for s in settings for m in summ[s]["methods"]})
    dx = 0.012 * max(float(np.ptp(sig)), 0.1)  # offset so overlapping CI bars stay readable
    for i, m in enumerate(methods):
        x = sig + (i - (len(methods) - 1) / 2) * dx
        est = [summ[s]["methods"].get(m, {}) for s in settings]
        _ci_line(axes[0, 0], x, [e.get("correct_final") for e in est], method_color(m), method_label(m))
        _ci_line(axes[0, 1], x, [e.get("log10_mgr95_final") for e in est], method_color(m), method_label(m))
    axes[0, 0].set_ylim(-0.02, 1.02)
    axes[0, 0].set_ylabel("correct ratio, final step")
    axes[0, 0].set_title("Correct ratio vs σ (higher is better)")
    for ax, metric in zip(axes[0], ("correct_final", "log10_mgr95_final")):
        vals = [number(getattr(summ[s]["methods"][m].get(metric), k, None), finite=True)
                for s in settings for m in methods
                if summ[s]["methods"].get(m, {}).get(metric) is not None for k in ("value", "low", "high")]
        finite = [x for x in vals if np.isfinite(x)]
        if metric.startswith("log10_mgr"):
            mgr_axis(ax, finite, axis="y")
        if finite and max(finite) - min(finite) < 1e-12:
            ax.text(0.5, 0.5, f"{metric_label(metric)} is {fmt(finite[0])} for every method and σ",
                    transform=ax.transAxes, ha="center", va="center", fontsize=8.5,
                    bbox={"boxstyle": "round", "fc": "white", "ec": "#999999", "alpha": 0.92})
    axes[0, 1].axhline(0.0, color="#777777", ls="--", lw=1)
    axes[0, 1].set_ylabel(mgr_scale_label("log10 MGR, 95th percentile,\nfinal step"), fontsize=8.5)
    axes[0, 1].set_title("Confident misclassification vs σ (lower is better)")
    for ax in axes[0]:
        ax.set_xlabel("localization noise σ (m)")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=3, frameon=False)
    R = min(summ[s]["n_realizations"] for s in settings) if settings else 0
    fig.suptitle(f"σ sweep on one track; bars: 95 % bootstrap CIs over {R} realizations "
                 "(localization noise only)")
    return fig


def fig_track(track: dict, biases: list[tuple[float, float]]) -> Any:
    fig, ax = new_figure(4.4, 4.2)
    cam = np.asarray(track.get("camera_xy") or [], float).reshape(-1, 2)
    hd = np.asarray(track.get("heading_rad") or [], float)
    ax.plot(cam[:, 0], cam[:, 1], "-", color="#888888", lw=1, zorder=1)
    ax.scatter(cam[:, 0], cam[:, 1], color="#000000", s=28, zorder=3, label="camera (dataset pose)")
    L = 0.08 * max(float(np.ptp(cam, axis=0).max()) if len(cam) > 1 else 1.0, 0.5)
    if hd.shape[0] == cam.shape[0]:
        ax.quiver(cam[:, 0], cam[:, 1], np.cos(hd) * L, np.sin(hd) * L, angles="xy", scale_units="xy",
                  scale=1, color="#000000", width=0.004, zorder=3)
    for k, (x, y) in enumerate(cam):
        ax.annotate(str(k), (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    for i, b in enumerate(biases):
        bc = cam + np.asarray(b, float)
        ax.scatter(bc[:, 0], bc[:, 1], facecolors="none", edgecolors="#999999", s=28, zorder=2,
                   label=f"biased estimate ({plain(b[0], signed=True)}, {plain(b[1], signed=True)}) m" if i < 3 else None)
        for p, q in zip(cam, bc):
            ax.plot([p[0], q[0]], [p[1], q[1]], color="#999999", lw=0.7, alpha=0.6, zorder=1)
    est, tru = track.get("object_xy_est"), track.get("object_xy_truth")
    if est is not None:
        ax.scatter([est[0]], [est[1]], marker="X", s=90, color="#E69F00", zorder=4,
                   label="object (ray-intersection estimate)")
    if tru is not None:
        ax.scatter([tru[0]], [tru[1]], marker="*", s=140, facecolors="none", edgecolors="black",
                   zorder=5, label="object (truth)")
    # "box", not "datalim": datalim moves the limits at draw time, after the layout placed the tick
    # labels, so a new end tick can fall off the canvas (the self-check caught it on a real track)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m, ground frame)")
    ax.set_ylabel("y (m, ground frame)")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=1, fontsize=8, frameon=False)
    return fig


def _pooled_over(pop: dict) -> str:
    """What the pooled rows' CIs vary over (the population's ``cluster``)."""
    c = pop.get("cluster")
    return "pooled: over targets too" if c in (None, "target") else f"pooled: over {varies_text(pop)}"
