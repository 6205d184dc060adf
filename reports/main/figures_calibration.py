"""Calibration figures: the reliability diagram of every method's pooled posteriors and the PIT
histograms of the test-domain fit (from summary.json's population block)."""
from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.evaluation.metrics.labels import method_color, method_label, ordered_methods
from reports.shared.figures import new_subplots
from reports.shared.numbers import fmt, percent, plain

KIND_TITLES = {"gp": "GP predictive alone (Model Based)", "gp_plus_dropout": "GP + dropout variance (With Uncertainty)",
               "gp_calibrated": "GP + cross-fitted test-domain variance",
               "gp_t": "GP predictive, Student-t (Model Based, t)",
               "gp_plus_dropout_t": "GP + dropout, Student-t (With Uncertainty, t)"}


RELIABILITY_COLUMNS = 3   # methods per row, so panel titles keep apart


def bin_counts(results, variant: str = "default", where: str = "final", n_bins: int | None = None) -> dict:
    """Posteriors per confidence bin and method ({method: counts (n_bins + 1,)}): the population's
    rows (biased and randomized experiments) of ``variant`` at each track's final step, or at every
    step; binned as the reliability diagram is (the last bin holds confidence 1 alone). Unweighted
    counts: how many posteriors each plotted point rests on."""
    import pandas as pd
    if results is None or "confidence" not in results or "variant" not in results or n_bins is None:
        return {}
    df = results[(results["variant"] == variant) & results["experiment"].isin(("biased", "randomized"))]
    if df.empty:
        return {}
    if where == "final":
        last = df.groupby(["target", "track", "experiment", "setting"])["step"].transform("max")
        df = df[df["step"] == last]
    conf = df["confidence"].to_numpy(float)       # max P of each posterior (results.parquet)
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    b = np.clip(np.searchsorted(edges, conf, side="right") - 1, 0, n_bins)
    out = {}
    for m, idx in pd.Series(np.arange(len(df))).groupby(df["method"].to_numpy()).groups.items():
        out[str(m)] = np.bincount(b[np.asarray(idx)], minlength=n_bins + 1)
    return out


def fig_reliability(pop: dict, where: str = "final", counts: dict | None = None) -> Any:
    """Accuracy against confidence per bin (marker area ~ share of the weight), one panel per method,
    at most ``RELIABILITY_COLUMNS`` per row; under each, the number of posteriors per bin (log
    scale). The diagonal is perfect calibration; the last bin (confidence exactly 1) is drawn at 1."""
    rel = pop.get("reliability") or {}
    methods = ordered_methods(rel.keys())
    n = max(len(methods), 1)
    ncol = min(n, RELIABILITY_COLUMNS)
    blocks = -(-n // ncol)
    has_counts = bool(counts)
    per = 2 if has_counts else 1
    fig, axes = new_subplots(blocks * per, ncol, w=0.8 + 3.2 * ncol, h=(4.4 if has_counts else 3.4) * blocks,
                             height_ratios=([3.0, 1.2] if has_counts else [1.0]) * blocks)
    for j in range(blocks * ncol):
        ax = axes[(j // ncol) * per, j % ncol]
        cax = axes[(j // ncol) * per + 1, j % ncol] if has_counts else None
        if j >= len(methods):
            ax.set_visible(False)
            if cax is not None:
                cax.set_visible(False)
            continue
        m = methods[j]
        d = (rel.get(m) or {}).get(where) or {}
        conf = np.array([np.nan if c is None else c for c in d.get("confidence", [])], float)
        acc = np.array([np.nan if a is None else a for a in d.get("accuracy", [])], float)
        share = np.array([0.0 if s is None else s for s in d.get("share", [])], float)
        ok = np.isfinite(conf) & np.isfinite(acc)
        ax.plot([0, 1], [0, 1], color="#888888", lw=0.8, ls="--")
        ax.plot(conf[ok], acc[ok], color=method_color(m), lw=1.2)
        ax.scatter(conf[ok], acc[ok], s=10 + 400 * share[ok], color=method_color(m), alpha=0.7, lw=0)
        ece = ((pop.get("pooled") or {}).get(m) or {}).get(f"ece_{where}") or {}
        ax.set_title(f"{method_label(m, short=True)}\nECE {fmt(ece.get('value'))}")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        if j % ncol == 0:
            ax.set_ylabel("accuracy in the bin")
        if cax is None:
            ax.set_xlabel("confidence (max P)")
            continue
        c = np.asarray(counts.get(m, []), float)
        lower = np.asarray(d.get("lower") or [], float)
        upper = np.asarray(d.get("upper") or [], float)
        if c.size and c.size == lower.size:
            width = np.where(upper > lower, upper - lower, 0.02)
            cax.bar(lower, np.maximum(c, 0.8), width=width, align="edge", color=method_color(m), alpha=0.6,
                    edgecolor="white")
            cax.set_yscale("log")
            cax.set_ylim(0.8, max(float(c.max()), 1.0) * 3)
            # plain decade labels: figure text is literal (no mathtext), so the default '10^k' would
            # print its markup
            from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
            cax.yaxis.set_major_locator(LogLocator(base=10, numticks=4))
            cax.yaxis.set_major_formatter(FuncFormatter(lambda x, _p: plain(x) if x < 1e4 else f"1e{round(np.log10(x))}"))
            cax.yaxis.set_minor_formatter(NullFormatter())
        cax.set_xlim(0, 1.02)
        cax.set_xlabel("confidence (max P)")
        if j % ncol == 0:
            cax.set_ylabel("posteriors\nin the bin")
    fig.suptitle(f"Reliability, {where} step{'s' if where == 'overall' else ''} (marker area: share of posteriors"
                 + ("; bars: how many posteriors each bin holds)" if has_counts else ")"))
    return fig


def fig_pit(domain: dict) -> Any:
    """PIT histograms of the crops' standardized residuals, pooled over classes and components, per
    variance model; flat at the dashed line when the model describes the test domain."""
    kinds = [k for k in KIND_TITLES if (domain.get(k) or {}).get("overall")]
    fig, axes = new_subplots(1, max(len(kinds), 1), w=0.8 + 3.0 * max(len(kinds), 1), h=3.0, sharey=True)
    for ax, k in zip(axes.flat, kinds):
        o = domain[k]["overall"]
        pit = np.asarray(o.get("pit") or [], float)
        if len(pit):
            edges = np.linspace(0, 1, len(pit) + 1)
            ax.bar(edges[:-1], pit, width=1 / len(pit), align="edge", color="#6699CC", edgecolor="white")
            ax.axhline(1 / len(pit), color="#333333", ls="--", lw=0.8)
        ax.set_title(f"{KIND_TITLES.get(k, k)}\n|z|>3: {percent(o.get('share_gt3') or 0, 1)}, "
                     f"95 % cover: {percent(o.get('coverage95') or 0)}", fontsize=9)
        ax.set_xlabel("PIT = Φ(z)")
    axes.flat[0].set_ylabel("share of (crop, component)")
    fig.suptitle("Test-domain fit: PIT of AVD crop scores under the own-class GP")
    return fig


def _n_bins(block: dict) -> int | None:
    rel = block.get("reliability") or {}
    first = next(iter(rel.values()), {}) or {}
    n = len((first.get("final") or {}).get("lower") or [])
    return n - 1 if n > 1 else None


def calibration_plan(pop: dict, results=None) -> list[tuple[str, Any]]:
    """(file name, builder) of the calibration figures this population can draw; ``results``
    (results.parquet) gives the posterior counts per bin."""
    plan = []
    if pop.get("reliability"):
        plan.append(("reliability.png", lambda: fig_reliability(
            pop, counts=bin_counts(results, "default", n_bins=_n_bins(pop)))))
    key = "evaluate.test_domain_variance=cross_fit"
    cal = (pop.get("ablations") or {}).get(key) or {}
    if cal.get("reliability"):
        plan.append(("reliability_calibrated.png", lambda: fig_reliability(
            cal, counts=bin_counts(results, key, n_bins=_n_bins(cal)))))
    if (pop.get("domain_fit") or {}).get("n_crops"):
        plan.append(("pit.png", lambda: fig_pit(pop["domain_fit"])))
    return plan
