"""Report sections on the class models with an instance term (``models.instance_term``;
docs/design.md §5, "Instances differ"): what the instance fits found (amplitude b, length scale λ
and b over the class amplitude a, per category and per component, every fit in a collapsed table,
and which classes got no term and why), what the term changes (each method against itself
without it: ``ablations.instance_term``), and the per-category breakdown (``by_category``) that
says where a method gains or loses. Every number is read from models/instance/index.json or
evaluate/summary.json; nothing is recomputed but quartiles of the fitted hyperparameters.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

from pipeline.evaluation.metrics.labels import (INSTANCE_ATTRIBUTION, INSTANCE_COMPARISONS, SIMPLE_BAYES, WU_INSTANCE,
                                                comparison_key, comparison_label, instance_goal_comparisons,
                                                method_label, ordered_methods)
from pipeline.evaluation.metrics.spec import metric_label
from pipeline.scene.folds import category_of
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt
from reports.shared.records import records_of, sentences
from reports.shared.tables import fit_diagnostics

INSTANCE = "instance_term"      # the block's key in summary.json's ablations (population_calibration)
KEYS = ("correct_final", "confident_error_final", "ece_final", "nll_final")
CATEGORY_KEYS = ("correct_final", "confident_error_final")


def category(name: str) -> str:
    """A fold class '<category>__f<k>' -> its category; any other class is its own."""
    try:
        return category_of(name)
    except ValueError:
        return str(name)


def _at_lower(d: dict, name: str) -> bool:
    return f"{name} at lower bound" in (d.get("at_bound") or [])


def _spread(values) -> str:
    """Median (q25–q75) of fitted values; '—' for none. Descriptive: fits, not draws."""
    v = np.asarray([x for x in values if x is not None], float)
    if not v.size:
        return "—"
    q25, q50, q75 = np.percentile(v, [25, 50, 75])
    return f"{fmt(q50)} ({fmt(q25)}–{fmt(q75)})"


def instance_fit_summary(index: dict) -> dict:
    """The instance fits of models/instance/index.json: ``fits`` (every record), ``active`` (a term
    whose amplitude left its lower bound), ``at_floor`` (fitted, amplitude at its lower bound: no
    term in effect), ``no_term`` ({class: why}: too few training instances)."""
    fits = fit_diagnostics(index)
    fitted = [d for d in fits if d.get("instance_term")]
    at_floor = [d for d in fitted if _at_lower(d, "instance_amplitude")]
    no_term = {}
    for d in fits:
        if not d.get("instance_term"):
            no_term.setdefault(str(d.get("class")), (d.get("n_instances"), d.get("instance_note") or "no instance term"))
    return {"fits": fits, "fitted": fitted, "active": [d for d in fitted if d not in at_floor], "at_floor": at_floor,
            "both_at_floor": [d for d in at_floor if _at_lower(d, "amplitude")], "no_term": no_term}


def _group_rows(groups: dict[str, list[dict]], n_fits: dict[str, int]) -> list[list]:
    """One row per group (every group with a fit, a term fitted or not)."""
    rows = []
    for name in sorted(n_fits):
        fits = groups.get(name, [])
        on = [d for d in fits if not _at_lower(d, "instance_amplitude")]
        rows.append([name, n_fits[name], len(fits), len(fits) - len(on),
                     _spread(d.get("instance_amplitude") for d in on),
                     _spread(d.get("instance_length_scale") for d in on),
                     _spread(d.get("instance_ratio") for d in on)])
    return rows


GROUP_HEADER = ["fits", "with a term fitted", "instance amplitude at its lower bound",
                "instance amplitude b", "instance length scale λ", "b / class amplitude a"]


def _component(d: dict) -> str:
    return str(d.get("component_name") or d.get("component"))


def instance_fits_section(ctx: ReportContext) -> None:
    index = getattr(ctx.run, "instance", None)
    if not isinstance(index, dict) or not fit_diagnostics(index):
        return
    ctx.section("Class models with an instance term: what the fits found", "instance-fits")
    page, s = ctx.page, instance_fit_summary(index)
    n, fitted = len(s["fits"]), len(s["fitted"])
    page.paragraph(
        f"Each class and component: s_i(θ) = m + g(θ) + h_i(θ) + ε, the instance deviation h_i with amplitude b and "
        f"length scale λ, fitted on the class's training instances (models/instance/index.json). Of the {n} fits "
        f"(class × component), {fitted} have two or more training instances and fit a term; in "
        f"{len(s['at_floor'])} of them b sits at its lower bound (no term in effect; {len(s['both_at_floor'])} of "
        f"those with the class amplitude a at its lower bound too: a component that barely varies for that "
        f"class). In the other {len(s['active'])}, b / a has median (quartiles) {_spread(d.get('instance_ratio') for d in s['active'])}"
        f" and λ {_spread(d.get('instance_length_scale') for d in s['active'])} (a long λ: a constant offset per "
        "instance; a ratio far above 1: the held-out instance's own deviation dominates its predictive).")
    if s["no_term"]:
        page.paragraph("No instance term: " + "; ".join(f"{c} ({why})" for c, (_, why) in sorted(s["no_term"].items()))
                       + ".", cls="note")
    by_cat, by_comp = defaultdict(list), defaultdict(list)
    fits_in_cat, fits_in_comp = defaultdict(int), defaultdict(int)
    for d in s["fits"]:
        fits_in_cat[category(str(d.get("class")))] += 1
        fits_in_comp[_component(d)] += 1
    for d in s["fitted"]:
        by_cat[category(str(d.get("class")))].append(d)
        by_comp[_component(d)].append(d)
    note = ("Median (25–75 % quartiles) over the fits whose instance amplitude left its lower bound: descriptive "
            "spreads of fitted values, not confidence intervals (each fit's Laplace 95 % interval of b is in the "
            "per-fit table).")
    page.table(["category"] + GROUP_HEADER, _group_rows(by_cat, fits_in_cat), cls="instance-fits-category",
               caption="Instance fits per category (its fold classes together). " + note)
    page.table(["component"] + GROUP_HEADER, _group_rows(by_comp, fits_in_comp), cls="instance-fits-component",
               caption="Instance fits per score component, over the classes. " + note)
    rows = [[d.get("class"), _component(d), d.get("n_instances"), d.get("amplitude"), d.get("instance_amplitude"),
             _laplace(d.get("instance_amplitude_ci")), d.get("instance_length_scale"), d.get("instance_ratio"),
             "; ".join(d.get("at_bound") or []) or (d.get("instance_note") or "—")] for d in s["fits"]]
    page.table(["class", "component", "training instances", "class amplitude a", "instance amplitude b",
                "b: 95 % interval (Laplace)", "instance length scale λ", "b / a", "at a bound / note"], rows,
               cls="instance-fits", collapsed=f"All {len(rows)} instance fits",
               caption="Per (class, component), from models/instance/index.json. The interval of b varies over "
                       "training sets drawn from the fitted model (Laplace approximation on the log scale).")


def _laplace(ci) -> str:
    return f"[{fmt(ci[0])}, {fmt(ci[1])}]" if isinstance(ci, (list, tuple)) and len(ci) == 2 else "—"


def instance_attribution_section(ctx: ReportContext) -> None:
    """Each method against itself without the instance term, on the same cells and realizations."""
    block = ((ctx.population or {}).get("ablations") or {}).get(INSTANCE)
    if not block:
        return
    ctx.section("What does the instance term change?", "instance-attribution")
    page, paired = ctx.page, block.get("paired") or {}
    rows = []
    for a, b in INSTANCE_COMPARISONS:
        per = paired.get(comparison_key(a, b))
        if per:
            rows.append([comparison_label(comparison_key(a, b)), INSTANCE_ATTRIBUTION[(a, b)]]
                        + [Estimate.of(per.get(k), signed=True) for k in KEYS])
    page.table(["comparison", "what it isolates"] + [metric_label(k, short=True) for k in KEYS], rows,
               cls="instance-attribution",
               caption="Paired differences [95 % CI] on the same cells and realizations, from the statistics engine "
                       "(CIs resample as the verdict does; NLL as the median over targets). Each instance method's "
                       "pooled values, ECE and reliability diagram are in the calibration section.")
    page.bullets(sentences(records_of(block), KEYS), cls="verdict instance-attribution")
    goal = instance_goal_comparisons(block.get("methods") or [])
    if not goal:
        return
    rows = [[method_label(b, short=True)] + [Estimate.of((paired.get(comparison_key(a, b)) or {}).get(k), signed=True)
                                             for k in CATEGORY_KEYS] for a, b in goal]
    page.table(["baseline"] + [f"{method_label(WU_INSTANCE, short=True)} − baseline: {metric_label(k, short=True)}"
                               for k in CATEGORY_KEYS], rows, cls="instance-goal",
               caption="The instance term's goal, pooled: paired differences [95 % CI over the design's clusters, "
                       "unadjusted] of With Uncertainty + instance against every baseline.")
    page.paragraph(goal_sentence(paired, goal), cls="instance-goal-verdict")


def goal_misses(paired: dict, goal) -> list[str]:
    """Where the goal fails (empty: met): a baseline whose confident-error difference's CI does not
    lie below 0, and a correct-ratio difference to Simple Bayes whose CI lies below 0."""
    out = []
    for a, b in goal:
        per = paired.get(comparison_key(a, b)) or {}
        e = Estimate.of(per.get("confident_error_final"), signed=True)
        if e.value is None or e.high is None or not float(e.high) < 0:
            out.append(f"confident errors not fewer than {method_label(b, short=True)}'s ({e.text()})")
        if b == SIMPLE_BAYES:
            c = Estimate.of(per.get("correct_final"), signed=True)
            if c.value is None or (c.high is not None and float(c.high) < 0):
                out.append(f"correct ratio below Simple Bayes's ({c.text()})")
    return out


def goal_sentence(paired: dict, goal) -> str:
    misses = goal_misses(paired, goal)
    head = ("Goal of the instance term (fewer confident errors than every baseline, each 95 % CI below 0; a correct "
            "ratio not worse than Simple Bayes's): ")
    return head + ("met." if not misses else "missed: " + "; ".join(misses) + " (differences of With Uncertainty + "
                   "instance − baseline).")


def category_section(ctx: ReportContext) -> None:
    """Per category: every method's correct ratio and confident-error rate, and the instance term's
    paired differences, CIs over that category's targets, then tracks."""
    by = (ctx.population or {}).get("by_category") or {}
    if not by:
        return
    ctx.section("Per category: where each method gains or loses", "by-category")
    page = ctx.page
    methods = ordered_methods({m for b in by.values() for m in (b.get("pooled") or {})})
    for k in CATEGORY_KEYS:
        rows = [[cat, len(b.get("targets") or [])] + [Estimate.of(((b.get("pooled") or {}).get(m) or {}).get(k))
                                                       for m in methods] for cat, b in sorted(by.items())]
        page.table(["category", "targets"] + [method_label(m, short=True) for m in methods], rows,
                   cls=f"by-category {k}",
                   caption=f"{metric_label(k)} per category, value [95 % CI over the category's targets, then their "
                           "tracks]: exploratory, no multiplicity adjustment.")
    pairs = [(a, b) for a, b in INSTANCE_COMPARISONS
             if any(comparison_key(a, b) in (v.get("paired") or {}) for v in by.values())]
    if not pairs:
        return
    header = ["category"] + [f"{comparison_label(comparison_key(a, b))}: {metric_label(k, short=True)}"
                             for a, b in pairs for k in CATEGORY_KEYS]
    rows = [[cat] + [Estimate.of((((b_.get("paired") or {}).get(comparison_key(a, b)) or {}).get(k)), signed=True)
                     for a, b in pairs for k in CATEGORY_KEYS] for cat, b_ in sorted(by.items())]
    page.table(header, rows, cls="by-category instance-paired",
               caption="The instance term's paired differences per category [95 % CI over the category's targets, "
                       "then tracks]: exploratory, unadjusted.")
    page.bullets(category_findings(by, pairs), cls="by-category-findings")
    goal = instance_goal_comparisons(methods)
    if goal:
        rows = [[cat, "met" if not goal_misses(b_.get("paired") or {}, goal) else "missed",
                 "; ".join(goal_misses(b_.get("paired") or {}, goal)) or "—"] for cat, b_ in sorted(by.items())]
        page.table(["category", "goal", "where it misses (With Uncertainty + instance − baseline [95 % CI])"], rows,
                   cls="by-category instance-goal-category",
                   caption="The instance term's goal per category, each difference's CI over that category's targets, "
                           "then tracks: exploratory, unadjusted.")


def category_findings(by: dict, pairs) -> list[str]:
    """Per instance comparison: the categories whose confident-error or correct-ratio difference
    has a CI that excludes 0, by direction (read off the intervals, never written by hand)."""
    out = []
    for a, b in pairs:
        key = comparison_key(a, b)
        for k, good in (("confident_error_final", "fewer"), ("correct_final", "more")):
            lower, higher = [], []
            for cat, blk in sorted(by.items()):
                e = Estimate.of(((blk.get("paired") or {}).get(key) or {}).get(k))
                if e.excludes_zero():
                    (lower if float(e.high) < 0 else higher).append(cat)
            what = "confident errors" if k.startswith("confident") else "correct answers"
            dec, inc = ((lower, higher) if good == "fewer" else (higher, lower))
            out.append(f"{comparison_label(key)}, {what}: {good} in {', '.join(dec) or 'no category'}; "
                       f"{'more' if good == 'fewer' else 'fewer'} in {', '.join(inc) or 'no category'} "
                       f"(95 % CI excludes 0, of {len(by)} categories; unadjusted).")
    return out
