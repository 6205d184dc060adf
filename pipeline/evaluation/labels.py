"""Method keys, display names and colours: the one place every stage, table and figure reads them.

Colours are from the Okabe-Ito colour-blind-safe palette; class colours (``CLASS_COLORS``) use
hues that no method uses, so a method and a class never share a colour on one page.
"""
from __future__ import annotations

from pipeline.method.names import (ATTRIBUTION, METHOD_SHORT, METHODS, MODEL_BASED, SIMPLE_BAYES,  # noqa: F401
                                   WITH_UNCERTAINTY, WU_DROPOUT_ONLY, WU_POSES_ONLY)

METHOD_LABELS = {
    WITH_UNCERTAINTY: "With Uncertainty (Feldman & Indelman)",
    MODEL_BASED: "Model Based (Teacy et al.)",
    SIMPLE_BAYES: "Simple Bayes",
    WU_POSES_ONLY: "With Uncertainty, poses only (dropout samples -> their mean)",
    WU_DROPOUT_ONLY: "With Uncertainty, dropout only (no pose sampling)",
}
METHOD_COLORS = {WITH_UNCERTAINTY: "#0072B2", MODEL_BASED: "#D55E00", SIMPLE_BAYES: "#009E73",
                 WU_POSES_ONLY: "#6699CC", WU_DROPOUT_ONLY: "#994F00"}

# Paired comparisons reported by the population evaluation: (method, baseline).
COMPARISONS = ((WITH_UNCERTAINTY, MODEL_BASED), (WITH_UNCERTAINTY, SIMPLE_BAYES))
# Attribution: each ingredient alone against Model Based, and what the full method adds to each.
ATTRIBUTION_COMPARISONS = ((WU_POSES_ONLY, MODEL_BASED), (WU_DROPOUT_ONLY, MODEL_BASED),
                           (WITH_UNCERTAINTY, WU_POSES_ONLY), (WITH_UNCERTAINTY, WU_DROPOUT_ONLY))


def comparison_key(method: str, baseline: str) -> str:
    return f"{method}-{baseline}"


# Class colours: no Okabe-Ito method hue (blue, vermillion, bluish green) among them.
CLASS_COLORS = ("#E69F00", "#56B4E9", "#CC79A7", "#F0E442", "#000000", "#999999",
                "#882255", "#44AA99", "#AA4499", "#117733", "#DDCC77", "#332288")

# Population metrics: key -> (label, True when larger is better).
METRICS = {
    "correct_final": ("correct ratio, final step", True),
    "correct_overall": ("correct ratio, all steps", True),
    "prob_truth_final": ("P(truth), final step", True),
    "msde_final": ("MSDE, final step", False),
    "log10_mgr75_final": ("log10 MGR 75th percentile, final step", False),
    "log10_mgr95_final": ("log10 MGR 95th percentile, final step", False),
    "log10_mgr75_overall": ("log10 MGR 75th percentile, all steps", False),
    "log10_mgr95_overall": ("log10 MGR 95th percentile, all steps", False),
    # Calibration of the posterior (pipeline.evaluation.calibration): cell means over realizations.
    "nll_final": ("NLL = -ln P(truth), final step", False),
    "nll_overall": ("NLL = -ln P(truth), all steps", False),
    "brier_final": ("Brier score, final step", False),
    "brier_overall": ("Brier score, all steps", False),
    "confident_error_final": ("confident-error rate (max P >= threshold on a wrong class), final step", False),
    "confident_error_overall": ("confident-error rate (max P >= threshold on a wrong class), all steps", False),
}
# Metrics of the pooled posteriors, not means of cell values (pipeline.evaluation.pooled_calibration).
POOLED_METRICS = {
    "ece_final": ("top-label ECE (15 bins), final step", False),
    "ece_overall": ("top-label ECE (15 bins), all steps", False),
}
MGR_AXIS_LABEL = "log10 MGR = log10(max_c P(c) / P(truth))"

# Short metric names for table headers (the long ones above are for sentences and captions).
METRIC_SHORT = {
    "correct_final": "correct, final",
    "correct_overall": "correct, all steps",
    "prob_truth_final": "P(truth), final",
    "msde_final": "MSDE, final",
    "log10_mgr75_final": "log10 MGR 75%, final",
    "log10_mgr95_final": "log10 MGR 95%, final",
    "log10_mgr75_overall": "log10 MGR 75%, all steps",
    "log10_mgr95_overall": "log10 MGR 95%, all steps",
    "nll_final": "NLL, final", "nll_overall": "NLL, all steps",
    "brier_final": "Brier, final", "brier_overall": "Brier, all steps",
    "confident_error_final": "confident errors, final", "confident_error_overall": "confident errors, all steps",
    "ece_final": "ECE, final", "ece_overall": "ECE, all steps",
}
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


def metric_label(key: str, short: bool = False) -> str:
    if short:
        return METRIC_SHORT.get(key, key)
    return METRICS[key][0] if key in METRICS else POOLED_METRICS[key][0] if key in POOLED_METRICS else key


def comparison_label(key: str, short: bool = True) -> str:
    """'with_uncertainty-model_based' -> 'With Uncertainty − Model Based'."""
    a, _, b = key.partition("-")
    return f"{method_label(a, short)} − {method_label(b, short)}" if b else key
