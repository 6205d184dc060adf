"""Method display names, colours and the paired comparisons, read off the method registry
(``pipeline.method.registry``: each method's class holds its own); every stage, table and figure
asks here. (Metric keys and labels live in ``pipeline.evaluation.metrics.spec``.)

Colours are from the Okabe-Ito colour-blind-safe palette; class colours (``CLASS_COLORS``) use
hues that no method uses, so a method and a class never share a colour on one page.
"""
from __future__ import annotations

from pipeline.method import registry
from pipeline.method.names import (ATTRIBUTION, MB_INSTANCE, MODEL_BASED, SIMPLE_BAYES,  # noqa: F401
                                   WITH_UNCERTAINTY, WU_DROPOUT_ONLY, WU_INSTANCE, WU_POSES_ONLY)


def methods() -> tuple[str, ...]:
    """The registered methods' keys in their order (the attribution variants apart)."""
    return registry.keys()


def comparisons() -> tuple[tuple[str, str], ...]:
    """Paired comparisons reported by the population evaluation: (method, baseline)."""
    return registry.comparisons()


# Attribution: each ingredient alone against Model Based, and what the full method adds to each.
ATTRIBUTION_COMPARISONS = ((WU_POSES_ONLY, MODEL_BASED), (WU_DROPOUT_ONLY, MODEL_BASED),
                           (WITH_UNCERTAINTY, WU_POSES_ONLY), (WITH_UNCERTAINTY, WU_DROPOUT_ONLY))


# The instance term's attribution: each method with the term against itself without it
# (the term alone; the term under poses and dropout), and what poses and dropout add on top of it.
INSTANCE_COMPARISONS = ((MB_INSTANCE, MODEL_BASED), (WU_INSTANCE, WITH_UNCERTAINTY), (WU_INSTANCE, MB_INSTANCE))
INSTANCE_ATTRIBUTION = {(MB_INSTANCE, MODEL_BASED): "the instance term alone (no pose or dropout sampling)",
                        (WU_INSTANCE, WITH_UNCERTAINTY): "the instance term with pose and dropout sampling",
                        (WU_INSTANCE, MB_INSTANCE): "pose and dropout sampling with the instance term"}


def instance_goal_comparisons(present) -> tuple[tuple[str, str], ...]:
    """With Uncertainty + instance against every baseline among ``present`` (method keys): the
    instance term's goal is stated against each (fewer confident errors, a correct ratio not worse
    than Simple Bayes's). With Uncertainty and Model Based + instance are in
    ``INSTANCE_COMPARISONS`` already."""
    skip = {WU_INSTANCE, MB_INSTANCE, WITH_UNCERTAINTY}
    return tuple((WU_INSTANCE, m) for m in present if m not in skip) if WU_INSTANCE in present else ()


def comparison_key(method: str, baseline: str) -> str:
    return f"{method}-{baseline}"


def in_primary_family(comparison: str, primary: bool) -> bool:
    """The declared primary family, whose verdicts are Holm-adjusted together (familywise 95 %:
    ``pipeline.evaluation.statistics.multiplicity``): With Uncertainty against each baseline
    (``comparisons()``) on each primary metric (``evaluate.primary_metrics``: by default the correct
    ratio and the confident-error rate at the final step). The bottom line and the scorecard read
    these adjusted verdicts; every other record is exploratory and left unadjusted."""
    return bool(primary) and comparison in {comparison_key(a, b) for a, b in comparisons()}


def present_comparisons(keys) -> list[tuple[str, str]]:
    """(method, baseline) of the comparison keys a results file holds: the known ones in their
    fixed order, then any others sorted (so a report shows what was computed, not a fixed list)."""
    keys = set(keys or ())
    known = [c for c in comparisons() if comparison_key(*c) in keys]
    rest = sorted(keys - {comparison_key(*c) for c in comparisons()})
    return known + [tuple(k.partition("-")[::2]) for k in rest]


# Class colours: no method hue (blue, vermillion, bluish green, reddish purple) among them.
CLASS_COLORS = ("#E69F00", "#56B4E9", "#661100", "#F0E442", "#000000", "#999999",
                "#882255", "#44AA99", "#AA4499", "#117733", "#DDCC77", "#332288")

UNKNOWN_COLOR = "#555555"


def method_label(method: str, short: bool = False) -> str:
    """Display name of a method key; an unknown key is shown as itself."""
    m = registry.get(method)
    # label and short are optional on a method of your own: the key (then the label) stands in
    label = method if m is None else getattr(m, "label", method)
    return getattr(m, "short", label) if short and m is not None else label


def method_color(method: str) -> str:
    m = registry.get(method)
    return UNKNOWN_COLOR if m is None else m.color


def method_note(method: str) -> str:
    """The method's one-line description (the report's method table)."""
    m = registry.get(method)
    return (m.note if m is not None else "") or "(no description)"


def ordered_methods(present) -> list[str]:
    """The registered methods in their order, then any others (the attribution variants) sorted."""
    present = set(present)
    order = registry.keys()
    return [m for m in order if m in present] + sorted(present - set(order))


def class_colors(n: int) -> list[str]:
    return [CLASS_COLORS[i % len(CLASS_COLORS)] for i in range(n)]


def comparison_label(key: str, short: bool = True) -> str:
    """'with_uncertainty-model_based' -> 'With Uncertainty − Model Based'."""
    a, _, b = key.partition("-")
    return f"{method_label(a, short)} − {method_label(b, short)}" if b else key
