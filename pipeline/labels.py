"""Method keys, display names and colours: the one place every stage, table and figure reads them.

Colours are from the Okabe-Ito colour-blind-safe palette; class colours (``CLASS_COLORS``) use
hues that no method uses, so a method and a class never share a colour on one page.
"""
from __future__ import annotations

WITH_UNCERTAINTY = "with_uncertainty"
MODEL_BASED = "model_based"
SIMPLE_BAYES = "simple_bayes"
METHODS = (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES)

METHOD_LABELS = {
    WITH_UNCERTAINTY: "With Uncertainty (Feldman & Indelman)",
    MODEL_BASED: "Model Based (Teacy et al.)",
    SIMPLE_BAYES: "Simple Bayes",
}
METHOD_SHORT = {WITH_UNCERTAINTY: "With Uncertainty", MODEL_BASED: "Model Based", SIMPLE_BAYES: "Simple Bayes"}
METHOD_COLORS = {WITH_UNCERTAINTY: "#0072B2", MODEL_BASED: "#D55E00", SIMPLE_BAYES: "#009E73"}

# Paired comparisons reported by the population evaluation: (method, baseline).
COMPARISONS = ((WITH_UNCERTAINTY, MODEL_BASED), (WITH_UNCERTAINTY, SIMPLE_BAYES))


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
}
MGR_AXIS_LABEL = "log10 MGR = log10(max_c P(c) / P(truth))"
