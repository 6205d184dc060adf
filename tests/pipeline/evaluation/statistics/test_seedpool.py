"""Seeds as a third bootstrap level: the CI covers training runs."""
import numpy as np

from pipeline.evaluation.statistics.seedpool import pooled_over_seeds, seed_pooled
from stages.commands.study import summarize


def _cells(level: float, rng, n_targets=6, n_tracks=3):
    out = []
    for t in range(n_targets):
        for k in range(n_tracks):
            for s in ("a", "b"):
                wu = level + rng.normal(0, 0.05)
                out.append({"target": f"t{t}", "track": k, "setting": s,
                            "values": {"with_uncertainty": {"correct_final": wu, "nll_final": 10 * wu},
                                       "model_based": {"correct_final": wu - 0.1, "nll_final": 10 * wu + 1}}})
    return out


def test_seed_level_widens_the_ci_when_seeds_disagree():
    rng = np.random.default_rng(0)
    agree = [[rng.normal(0.5, 0.02, 3) for _ in range(6)] for _ in range(3)]
    differ = [[g + off for g in seed] for seed, off in zip(agree, (-0.3, 0.0, 0.3))]
    a = pooled_over_seeds(agree, 500, 0, "mean")
    d = pooled_over_seeds(differ, 500, 0, "mean")
    assert abs(d["value"] - a["value"]) < 1e-12
    assert (d["ci_high"] - d["ci_low"]) > 5 * (a["ci_high"] - a["ci_low"])
    assert d["n_seeds"] == 3 and len(d["per_seed"]) == 3


def test_seed_pooled_verdict_and_study_summary():
    rng = np.random.default_rng(1)
    cells = {"0": _cells(0.6, rng), "1": _cells(0.7, rng)}
    out = seed_pooled(cells, ["with_uncertainty", "model_based"], ["correct_final", "nll_final"],
                      [("with_uncertainty", "model_based")], 400)
    d = out["paired"]["with_uncertainty-model_based"]
    assert abs(d["correct_final"]["value"] - 0.1) < 1e-9 and d["correct_final"]["ci_low"] > 0
    assert abs(d["nll_final"]["value"] + 1) < 1e-9
    assert [r["outcome"] for r in out["verdict_table"]] == ["better", "better"]
    assert "over 2 seeds" in out["verdict"][0]
    res = {s: {"pooled": {}, "verdict": [], "verdict_table": [], "cells": c} for s, c in ((0, cells["0"]), (1, cells["1"]))}
    summ = summarize(res, 300)
    assert summ["pooled_over_seeds"]["verdict_table"][0]["outcome"] == "better"
    assert "cells" not in summ["per_seed"]["0"]
