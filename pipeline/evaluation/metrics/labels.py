"""Method keys, display names and colours: the one place every stage, table and figure reads them.
(Metric keys and labels live in ``pipeline.evaluation.metrics.spec``.)

Colours are from the Okabe-Ito colour-blind-safe palette; class colours (``CLASS_COLORS``) use
hues that no method uses, so a method and a class never share a colour on one page.
"""
from __future__ import annotations

from pipeline.method.names import (ATTRIBUTION, DIRICHLET, METHOD_SHORT, METHODS, MODEL_BASED,  # noqa: F401
                                   SIMPLE_BAYES, WITH_UNCERTAINTY, WU_DROPOUT_ONLY, WU_POSES_ONLY)

METHOD_LABELS = {
    WITH_UNCERTAINTY: "With Uncertainty (Feldman & Indelman)",
    MODEL_BASED: "Model Based (Teacy et al.)",
    SIMPLE_BAYES: "Simple Bayes",
    DIRICHLET: "Dirichlet (Tchuiev & Indelman)",
    WU_POSES_ONLY: "With Uncertainty, poses only (dropout samples -> their mean)",
    WU_DROPOUT_ONLY: "With Uncertainty, dropout only (no pose sampling)",
}
METHOD_COLORS = {WITH_UNCERTAINTY: "#0072B2", MODEL_BASED: "#D55E00", SIMPLE_BAYES: "#009E73",
                 DIRICHLET: "#CC79A7", WU_POSES_ONLY: "#6699CC", WU_DROPOUT_ONLY: "#994F00"}

# Paired comparisons reported by the population evaluation: (method, baseline).
COMPARISONS = ((WITH_UNCERTAINTY, MODEL_BASED), (WITH_UNCERTAINTY, SIMPLE_BAYES), (WITH_UNCERTAINTY, DIRICHLET))
# Attribution: each ingredient alone against Model Based, and what the full method adds to each.
ATTRIBUTION_COMPARISONS = ((WU_POSES_ONLY, MODEL_BASED), (WU_DROPOUT_ONLY, MODEL_BASED),
                           (WITH_UNCERTAINTY, WU_POSES_ONLY), (WITH_UNCERTAINTY, WU_DROPOUT_ONLY))


def comparison_key(method: str, baseline: str) -> str:
    return f"{method}-{baseline}"


def present_comparisons(keys) -> list[tuple[str, str]]:
    """(method, baseline) of the comparison keys a results file holds: the known ones in their
    fixed order, then any others sorted (so a report shows what was computed, not a fixed list)."""
    keys = set(keys or ())
    known = [c for c in COMPARISONS if comparison_key(*c) in keys]
    rest = sorted(keys - {comparison_key(*c) for c in COMPARISONS})
    return known + [tuple(k.partition("-")[::2]) for k in rest]


# Class colours: no method hue (blue, vermillion, bluish green, reddish purple) among them.
CLASS_COLORS = ("#E69F00", "#56B4E9", "#661100", "#F0E442", "#000000", "#999999",
                "#882255", "#44AA99", "#AA4499", "#117733", "#DDCC77", "#332288")

UNKNOWN_COLOR = "#555555"


def method_label(method: str, short: bool = False) -> str:
    """Display name of a method key; an unknown key is shown as itself."""
    return (METHOD_SHORT if short else METHOD_LABELS).get(method, method)


def method_color(method: str) -> str:
    return METHOD_COLORS.get(method, UNKNOWN_COLOR)


def ordered_methods(present) -> list[str]:
    """The known methods in their fixed order, then any unknown ones sorted."""
    present = set(present)
    return [m for m in METHODS if m in present] + sorted(present - set(METHODS))


def class_colors(n: int) -> list[str]:
    return [CLASS_COLORS[i % len(CLASS_COLORS)] for i in range(n)]


def comparison_label(key: str, short: bool = True) -> str:
    """'with_uncertainty-model_based' -> 'With Uncertainty − Model Based'."""
    a, _, b = key.partition("-")
    return f"{method_label(a, short)} − {method_label(b, short)}" if b else key
