"""The reliability diagram's posteriors per bin: counted at each track's final step, binned as the
diagram is (the last bin holds confidence 1 alone), only the population's rows of one variant."""
from __future__ import annotations

import numpy as np
import pandas as pd

from reports.main.figures_calibration import bin_counts, fig_reliability
from reports.shared.checks import figure_text_problems


def _rows():
    rows = []
    for track, confs in ((0, (0.5, 0.95, 1.0)), (1, (0.2, 0.55))):
        for step, c in enumerate(confs):
            for variant, exp in (("default", "randomized"), ("default", "sensitivity"), ("other", "randomized")):
                rows.append({"variant": variant, "experiment": exp, "target": "t", "track": track, "setting": "s",
                             "step": step, "method": "with_uncertainty", "confidence": c})
    return pd.DataFrame(rows)


def test_counts_take_each_tracks_final_step_of_the_variant_and_bin_confidence_one_alone():
    counts = bin_counts(_rows(), "default", "final", n_bins=10)["with_uncertainty"]
    assert counts.tolist() == [0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]     # 0.55 in bin 5, 1.0 in its own bin
    every = bin_counts(_rows(), "default", "overall", n_bins=10)["with_uncertainty"]
    assert every.sum() == 5 and every[9] == 1 and every[2] == 1


def test_a_reliability_figure_of_six_methods_keeps_three_a_row_and_its_text_apart():
    methods = ("with_uncertainty", "model_based", "simple_bayes", "dirichlet", "with_uncertainty_poses_only",
               "with_uncertainty_dropout_only")
    edges = np.linspace(0, 1, 11)
    rel = {"lower": list(edges[:-1]) + [1.0], "upper": list(edges[1:]) + [1.0], "share": [1 / 11] * 11,
           "confidence": list(edges[:-1] + 0.05) + [1.0], "accuracy": list(edges[:-1]) + [0.9]}
    pop = {"reliability": {m: {"final": rel} for m in methods},
           "pooled": {m: {"ece_final": {"value": 0.1}} for m in methods}}
    fig = fig_reliability(pop, counts={m: np.arange(11) * 10 for m in methods})
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 12 and max(len(row) for row in np.asarray(fig.axes).reshape(4, 3)) == 3
    assert figure_text_problems(fig, "reliability") == []
