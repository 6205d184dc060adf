"""Report sections on the methods with an instance term (docs/design.md §5, "Instances differ"):
what the term changes (each method against itself without it: its block of the ablations), and
the per-category breakdown (``by_category``) that says where a method gains or loses. Every number
is read from evaluate/summary.json. What the instance fits found is their provider's section
(shown by ``reports.main.provided``).
"""
from __future__ import annotations

from pipeline.evaluation.metrics.labels import (INSTANCE_ATTRIBUTION, INSTANCE_COMPARISONS, SIMPLE_BAYES, WU_INSTANCE,
                                                comparison_key, comparison_label, instance_goal_comparisons,
                                                method_label, ordered_methods)
from pipeline.evaluation.grid.population_calibration import INSTANCE_KEY
from pipeline.evaluation.metrics.spec import metric_label
from pipeline.scene.folds import category_of
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate
from reports.shared.records import find, records_of, sentences

INSTANCE = INSTANCE_KEY      # the block's key in summary.json's ablations
KEYS = ("correct_final", "confident_error_final", "ece_final", "nll_final")
CATEGORY_KEYS = ("correct_final", "confident_error_final")


def category(name: str) -> str:
    """A fold class '<category>__f<k>' -> its category; any other class is its own."""
    try:
        return category_of(name)
    except ValueError:
        return str(name)


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
                        + _shown(ctx, block, comparison_key(a, b), KEYS, "instance-term table"))
    page.table(["comparison", "what it isolates"] + [metric_label(k, short=True) for k in KEYS], rows,
               cls="instance-attribution",
               caption="Paired differences [95 % CI] on the same cells and realizations, from the statistics engine "
                       "(CIs resample as the verdict does; NLL as the median over targets). Each instance method's "
                       "pooled values, ECE and reliability diagram are in the calibration section.")
    page.bullets(sentences(records_of(block), KEYS), cls="verdict instance-attribution")
    goal = instance_goal_comparisons(block.get("methods") or [])
    if not goal:
        return
    rows = [[method_label(b, short=True)] + _shown(ctx, block, comparison_key(a, b), CATEGORY_KEYS,
                                                   "instance goal table") for a, b in goal]
    page.table(["baseline"] + [f"{method_label(WU_INSTANCE, short=True)} − baseline: {metric_label(k, short=True)}"
                               for k in CATEGORY_KEYS], rows, cls="instance-goal",
               caption="The instance term's goal, pooled: paired differences [95 % CI over the design's clusters, "
                       "unadjusted] of With Uncertainty + instance against every baseline.")
    page.paragraph(goal_sentence(paired, goal), cls="instance-goal-verdict")


def _shown(ctx: ReportContext, block: dict, key: str, metrics, where: str) -> list[Estimate]:
    """The block's paired differences of ``key`` as the table shows them, each registered in the
    page's ledger against its verdict record (one statistic per number)."""
    per = (block.get("paired") or {}).get(key) or {}
    out = [Estimate.of(per.get(k), signed=True) for k in metrics]
    for k, e in zip(metrics, out):
        ctx.ledger.register_record(("ablation", INSTANCE, key, k), e, find(records_of(block), key, k), where=where)
    return out


def goal_misses(paired: dict, goal) -> list[str]:
    """Where the goal fails (empty: met): a baseline whose confident-error difference's CI does not
    lie below 0, and a correct-ratio difference to Simple Bayes whose CI lies below 0. A withheld
    difference (no CI: ``design.withheld``) is no miss: ``goal_withheld`` names it."""
    out = []
    for a, b in goal:
        per = paired.get(comparison_key(a, b)) or {}
        e = Estimate.of(per.get("confident_error_final"), signed=True)
        if not _held(per, "confident_error_final") and (e.value is None or e.high is None or not float(e.high) < 0):
            out.append(f"confident errors not fewer than {method_label(b, short=True)}'s ({e.text()})")
        if b == SIMPLE_BAYES and not _held(per, "correct_final"):
            c = Estimate.of(per.get("correct_final"), signed=True)
            if c.value is None or (c.high is not None and float(c.high) < 0):
                out.append(f"correct ratio below Simple Bayes's ({c.text()})")
    return out


def _held(per: dict, metric: str) -> str:
    return str((per.get(metric) or {}).get("withheld") or "")


def goal_withheld(paired: dict, goal) -> list[str]:
    """The goal's differences that carry no CI and no verdict (withheld), each with its level."""
    out = []
    for a, b in goal:
        per = paired.get(comparison_key(a, b)) or {}
        for k in ("confident_error_final",) + (("correct_final",) if b == SIMPLE_BAYES else ()):
            if _held(per, k):
                out.append(f"{metric_label(k, short=True)} against {method_label(b, short=True)} "
                           f"({_held(per, k).split(':')[0]})")
    return out


def goal_state(paired: dict, goal) -> str:
    """'met', 'missed', or 'not judged' (no miss, but a difference without a CI)."""
    return "missed" if goal_misses(paired, goal) else "not judged" if goal_withheld(paired, goal) else "met"


def goal_sentence(paired: dict, goal) -> str:
    misses, held = goal_misses(paired, goal), goal_withheld(paired, goal)
    head = ("Goal of the instance term (fewer confident errors than every baseline, each 95 % CI below 0; a correct "
            "ratio not worse than Simple Bayes's): ")
    no_ci = (f"no CI, no verdict on {', '.join(held)} (too few units)" if held else "")
    if not misses:
        return head + (f"not judged: {no_ci}." if held else "met.")
    return head + ("missed: " + "; ".join(misses) + " (differences of With Uncertainty + instance − baseline)"
                   + (f"; {no_ci}" if held else "") + ".")


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
        rows = [[cat, goal_state(b_.get("paired") or {}, goal),
                 "; ".join(goal_misses(b_.get("paired") or {}, goal) + [f"no CI, no verdict: {h}" for h in
                                                                         goal_withheld(b_.get("paired") or {}, goal)])
                 or "—"] for cat, b_ in sorted(by.items())]
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
            lower, higher, held = [], [], []
            for cat, blk in sorted(by.items()):
                d = ((blk.get("paired") or {}).get(key) or {}).get(k) or {}
                e = Estimate.of(d)
                if d.get("withheld"):   # no CI, no verdict: named apart, never among "no category"
                    held.append((cat, str(d["withheld"]).split(":")[0]))
                elif e.excludes_zero():
                    (lower if float(e.high) < 0 else higher).append(cat)
            what = "confident errors" if k.startswith("confident") else "correct answers"
            dec, inc = ((lower, higher) if good == "fewer" else (higher, lower))
            tested = len(by) - len(held)
            none = "no category" if tested else "no category with a CI"
            out.append(f"{comparison_label(key)}, {what}: {good} in {', '.join(dec) or none}; "
                       f"{'more' if good == 'fewer' else 'fewer'} in {', '.join(inc) or none} "
                       f"(95 % CI excludes 0, of {tested} categories with a CI; unadjusted)"
                       + (f"; no CI, no verdict in {', '.join(f'{c} ({w})' for c, w in held)} (too few units)"
                          if held else "") + ".")
    return out
