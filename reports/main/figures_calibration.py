"""Calibration figures: the reliability diagram of every method's pooled posteriors and the PIT
histograms of the test-domain fit (from summary.json's population block)."""
from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.evaluation.metrics.labels import method_color, method_label, ordered_methods
from reports.shared.figures import new_subplots

KIND_TITLES = {"gp": "GP predictive alone (Model Based)", "gp_plus_dropout": "GP + dropout variance (With Uncertainty)",
               "gp_calibrated": "GP + cross-fitted test-domain variance"}


def fig_reliability(pop: dict, where: str = "final") -> Any:
    """Accuracy against confidence per bin (marker area ~ share of the weight), one panel per method;
    the diagonal is perfect calibration. The last bin (confidence exactly 1) is drawn at 1."""
    rel = pop.get("reliability") or {}
    methods = ordered_methods(rel.keys())
    fig, axes = new_subplots(1, max(len(methods), 1), w=0.8 + 3.0 * max(len(methods), 1), h=3.4, sharey=True)
    for ax, m in zip(axes.flat, methods):
        d = (rel.get(m) or {}).get(where) or {}
        conf = np.array([np.nan if c is None else c for c in d.get("confidence", [])], float)
        acc = np.array([np.nan if a is None else a for a in d.get("accuracy", [])], float)
        share = np.array([0.0 if s is None else s for s in d.get("share", [])], float)
        ok = np.isfinite(conf) & np.isfinite(acc)
        ax.plot([0, 1], [0, 1], color="#888888", lw=0.8, ls="--")
        ax.plot(conf[ok], acc[ok], color=method_color(m), lw=1.2)
        ax.scatter(conf[ok], acc[ok], s=10 + 400 * share[ok], color=method_color(m), alpha=0.7, lw=0)
        ece = ((pop.get("pooled") or {}).get(m) or {}).get(f"ece_{where}") or {}
        ax.set_title(f"{method_label(m, short=True)}\nECE {ece.get('value', float('nan')):.3f}")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("confidence (max P)")
    axes.flat[0].set_ylabel("accuracy in the bin")
    fig.suptitle(f"Reliability, {where} step{'s' if where == 'overall' else ''} (marker area: share of posteriors)")
    return fig


def fig_pit(domain: dict) -> Any:
    """PIT histograms of the crops' standardized residuals, pooled over classes and components, per
    variance model; flat at the dashed line when the model describes the test domain."""
    kinds = [k for k in ("gp", "gp_plus_dropout", "gp_calibrated") if (domain.get(k) or {}).get("overall")]
    fig, axes = new_subplots(1, max(len(kinds), 1), w=0.8 + 3.0 * max(len(kinds), 1), h=3.0, sharey=True)
    for ax, k in zip(axes.flat, kinds):
        o = domain[k]["overall"]
        pit = np.asarray(o.get("pit") or [], float)
        if len(pit):
            edges = np.linspace(0, 1, len(pit) + 1)
            ax.bar(edges[:-1], pit, width=1 / len(pit), align="edge", color="#6699CC", edgecolor="white")
            ax.axhline(1 / len(pit), color="#333333", ls="--", lw=0.8)
        ax.set_title(f"{KIND_TITLES.get(k, k)}\n|z|>3: {100 * (o.get('share_gt3') or 0):.1f} %, "
                     f"95 % cover: {100 * (o.get('coverage95') or 0):.0f} %", fontsize=9)
        ax.set_xlabel("PIT = Φ(z)")
    axes.flat[0].set_ylabel("share of (crop, component)")
    fig.suptitle("Test-domain fit: PIT of AVD crop scores under the own-class GP")
    return fig


def calibration_plan(pop: dict) -> list[tuple[str, Any]]:
    """(file name, builder) of the calibration figures this population can draw."""
    plan = []
    if pop.get("reliability"):
        plan.append(("reliability.png", lambda: fig_reliability(pop)))
    cal = (pop.get("ablations") or {}).get("evaluate.test_domain_variance=cross_fit") or {}
    if cal.get("reliability"):
        plan.append(("reliability_calibrated.png", lambda: fig_reliability(cal)))
    if (pop.get("domain_fit") or {}).get("n_crops"):
        plan.append(("pit.png", lambda: fig_pit(pop["domain_fit"])))
    return plan
