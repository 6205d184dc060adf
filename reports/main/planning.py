"""The view-planning section: where to look next (docs/planning.md). Everything shown is the
evaluate stage's ``planning`` block of summary.json: the per-step curves with their CIs, the
pooled table, the verdict sentences (computed there from the paired CIs) and one example path.
Nothing is recomputed here."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.evaluation.statistics.records import record
from pipeline.planning.planners import PLANNERS
from reports.main.context import ReportContext
from reports.shared.figures import mgr_axis, new_subplots, step_ticks
from reports.shared.numbers import Estimate, fmt
from reports.shared.records import sentence

# A planner's label and colour are its registry entry's (``Planner.label``, ``Planner.color``); a
# planner not registered in this process (a run read back after its package was removed) shows as
# its key with spaces, in this colour.
UNKNOWN_COLOUR = "#CC79A7"


def name(p: str) -> str:
    return PLANNERS[p].label if p in PLANNERS else p.replace("_", " ")


def colour(p: str) -> str:
    return PLANNERS[p].color if p in PLANNERS else UNKNOWN_COLOUR


def scope(block: dict) -> str:
    return str(block.get("scope", "")).replace(" x ", " × ")


CURVES = (("correct", "correct ratio"), ("confident_error", "confident-error rate"), ("nll", "NLL of the truth"))


def verdict_records(block: dict) -> list[dict]:
    """The paired entries on steps to a decision and on the correct ratio at a step as verdict
    records (``records.record``: the one outcome rule), so they are worded and checked as every
    other verdict."""
    out = []
    for comp, entries in (block.get("paired") or {}).items():
        for m, est in entries.items():
            if m != "steps_to_decision" and not m.startswith("correct_at"):
                continue
            out.append(record(comp, m, est, pooling=est.get("pooling", "mean"), better=est.get("better", "higher"),
                              over=est.get("over") or ["targets", "starts"], n=est.get("n") or {}, primary=True,
                              **({"withheld": est["withheld"]} if est.get("withheld") else {})))
    return out


def verdict_sentences(block: dict) -> list[str]:
    """One sentence per verdict record, by the one renderer (``reports.shared.records.sentence``)."""
    labels = block.get("labels") or {}
    return [sentence(r, name=name, metric_name=lambda m: labels.get(m, m)) for r in verdict_records(block)]


def curves_caption(block: dict) -> str:
    """The curves' finding: each planner's correct ratio at the last step, highest first."""
    last = int(block["budget"])
    final = {p: block["curves"][p]["correct"][-1] for p in block["planners"]}
    order = sorted(final, key=lambda p: -(final[p].get("value") or 0.0))
    vals = "; ".join(f"{name(p)} {Estimate.of(final[p]).text()}" for p in order)
    return (f"Metrics per step, mean over targets with 95 % CIs. Correct ratio at step {last}, highest first: "
            f"{vals}.")


def map_caption(block: dict) -> str:
    """The map's finding: how many views each path took and how many views both share."""
    ex = block.get("example") or {}
    paths = ex.get("paths") or {}
    ig, fx = (paths.get(p, {}).get("nodes") or [] for p in ("info_gain", "fixed"))
    return (f"One planned path against the fixed track from the same start (true positions; target "
            f"{ex.get('target', '?')}, biased setting): information gain took {len(ig)} views, the fixed track "
            f"{len(fx)}; {len(set(ig) & set(fx))} views are the same on both.")


def _block(ctx: ReportContext) -> dict | None:
    b = (ctx.ev.summary or {}).get("planning")
    return b if isinstance(b, dict) and b.get("curves") else None


def fig_curves(block: dict) -> Any:
    fig, axes = new_subplots(1, len(CURVES), w=10.0, h=3.4)
    steps = np.arange(1, int(block["budget"]) + 1)
    for ax, (key, label) in zip(axes[0], CURVES):
        seen = []
        for p in block["planners"]:
            est = block["curves"][p][key]
            v = np.array([e["value"] for e in est], float)
            lo = np.array([e["ci_low"] for e in est], float)
            hi = np.array([e["ci_high"] for e in est], float)
            ax.plot(steps, v, "-o", ms=3, color=colour(p), label=name(p), lw=1.4)
            ax.fill_between(steps, lo, hi, color=colour(p), alpha=0.12, lw=0)
            seen.extend([*v, *lo, *hi])
        ax.set_title(label)
        if key == "nll":   # unbounded: a few confidently wrong targets would flatten a linear axis
            mgr_axis(ax, seen)
            ax.set_ylabel("symlog axis: linear in [0, 1]", fontsize=7)
        ax.set_xlabel("step (measurements)")
        step_ticks(ax, steps)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=6, fontsize=8,
               frameon=False)
    return fig


def fig_map(example: dict) -> Any:
    fig, axes = new_subplots(1, 1, w=5.0, h=4.6)
    ax = axes[0, 0]
    views = np.asarray(example["views_xy"], float).reshape(-1, 2)
    ax.scatter(views[:, 0], views[:, 1], s=10, color="#CCCCCC", label="views that see the target", zorder=1)
    for key, style in (("fixed", "--"), ("info_gain", "-")):
        path = (example.get("paths") or {}).get(key)
        if not path:
            continue
        xy = np.asarray(path["xy"], float).reshape(-1, 2)
        jitter = 0.01 if key == "fixed" else 0.0     # the two paths share their start
        ax.plot(xy[:, 0] + jitter, xy[:, 1] + jitter, style, marker="o", ms=4, color=colour(key),
                label=f"{name(key)} ({len(xy)} measurements)", zorder=3)
    o = example["object_xy"]
    ax.scatter([o[0]], [o[1]], marker="X", s=90, color="#D55E00", label="object (estimate)", zorder=4)
    start = np.asarray(example["paths"]["info_gain"]["xy"][0] if "info_gain" in example["paths"] else views[0])
    ax.scatter([start[0]], [start[1]], marker="s", s=50, facecolors="none", edgecolors="black", label="start", zorder=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, ground frame)")
    ax.set_ylabel("y (m, ground frame)")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    return fig


def planning_plan(ctx: ReportContext) -> list[tuple[str, Callable[[], Any]]]:
    block = _block(ctx)
    if block is None:
        return []
    plan = [("planning_curves.png", lambda: fig_curves(block))]
    best = max(block["planners"], key=lambda p: block["curves"][p]["correct"][-1]["value"])
    ctx.alts["planning_curves.png"] = (f"Correct ratio, confident-error rate and NLL per step for each planner; "
                                       f"highest correct ratio at the last step: {name(best)}.")
    if (block.get("example") or {}).get("paths"):
        ex = block["example"]
        plan.append(("planning_map.png", lambda: fig_map(ex)))
        ctx.alts["planning_map.png"] = (f"Floor plan of {ex['scan']}: the information-gain path and the fixed track "
                                        f"from the same start, target {ex['target']}.")
    return plan


def _ci(e: dict) -> str:
    return Estimate.of(e).text()


def planning_section(ctx: ReportContext) -> None:
    block = _block(ctx)
    if block is None:
        return
    ctx.section("View planning: where to look next", "planning")
    ctx.page.paragraph(
        f"Each planner drives the robot on the scan's move graph from the same start nodes "
        f"({scope(block)}), for at most {block['budget']} measurements, stopping when max P ≥ "
        f"{fmt(block['confidence'])}; every planner's views are fused by With Uncertainty, so the "
        f"differences are the choice of views alone. Information gain maximises the expected information "
        f"gain under the belief's localization samples, its known-pose variant the same with the pose taken as "
        f"known, hindsight chooses with the true class (an upper bound). Values are means over targets with "
        f"95 % CIs (hierarchical bootstrap over targets, then starts).")
    ctx.figure("planning_curves.png", curves_caption(block))
    at = [k for k in block.get("at_steps", []) if f"correct_at_{k}" in block["pooled"][block["planners"][0]]]
    rows = [[name(p), _ci(block["pooled"][p]["steps_to_decision"])] + [_ci(block["pooled"][p][f"correct_at_{k}"]) for k in at]
            for p in block["planners"]]
    ctx.page.table(["planner", "steps to a confident correct decision"] + [f"correct ratio at step {k}" for k in at],
                   rows, cls="planning", caption=f"Pooled over {scope(block)}; no confident correct decision within the budget "
                                 f"counts as {block['budget'] + 1} steps.")
    for r in verdict_records(block):
        ctx.ledger.register(("planning", r["comparison"], r["metric"]), r["value"], r["lo"], r["hi"],
                            label=r["outcome"], where="planning verdicts", higher_is_better=r["better"] == "higher")
    sentences = verdict_sentences(block)
    if sentences:
        ctx.page.bullets(sentences)
    t = (ctx.ev.summary or {}).get("timings_s") or {}
    if t.get("planning_decision_ms_median") is not None:
        ctx.page.paragraph(f"One information-gain decision took {fmt(t['planning_decision_ms_median'])} ms (median; "
                           f"90th percentile {fmt(t['planning_decision_ms_p90'])} ms) over "
                           f"{int(t['planning_decisions'])} decisions.")
    ctx.figure("planning_map.png", map_caption(block))
