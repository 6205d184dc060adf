"""Which (target, track) the paper's single-track figures show: chosen by a rule, not by position.

The first target's first track can be a total failure (every method ends wrong), which shows
nothing about how the methods differ. The rule picks the track where the methods disagree most at
the final step: the spread (max − min over methods) of the final-step correct ratio, averaged over
the track's settings; ties go to the larger spread of final-step P(truth), then to the first
(target, track) in sorted order, so the choice is deterministic and needs no random draw. The
choice and its scores are recorded in ``summary.json`` (``showcase``).
"""
from __future__ import annotations

import pandas as pd

RULE = ("the (target, track) of the default variant whose methods disagree most at the final step: largest "
        "spread (max − min over methods) of the final-step correct ratio, averaged over the track's settings; "
        "ties: larger spread of final-step P(truth), then the first (target, track) in sorted order")


def choose(table: pd.DataFrame, variant: str = "default") -> dict:
    """``table``: one row per (variant, target, track, setting, method) with ``correct_final`` and
    ``prob_truth_final``. Returns {"target", "track", "rule", "correct_spread", "p_truth_spread",
    "candidates", "ties"}."""
    d = table[table["variant"] == variant] if "variant" in table else table
    if d.empty:
        raise ValueError("showcase: no cells of the default variant to choose from")
    keys = ["target", "track", "setting"]
    spread = d.groupby(keys)[["correct_final", "prob_truth_final"]].agg(lambda x: float(x.max() - x.min()))
    per_track = spread.groupby(level=["target", "track"]).mean().reset_index()
    per_track = per_track.sort_values(["correct_final", "prob_truth_final", "target", "track"],
                                      ascending=[False, False, True, True], kind="mergesort")
    top = per_track.iloc[0]
    ties = int(((per_track["correct_final"] == top["correct_final"])
                & (per_track["prob_truth_final"] == top["prob_truth_final"])).sum()) - 1
    return {"target": str(top["target"]), "track": int(top["track"]), "rule": RULE,
            "correct_spread": float(top["correct_final"]), "p_truth_spread": float(top["prob_truth_final"]),
            "candidates": int(len(per_track)), "ties": ties}
