"""The bottom line reads the declared primary comparison (``population.primary``) first, with its
own interval and verdict; the primary_metrics family follows, labelled exploratory."""
from reports.main.bottom_line import bottom_line, primary_line


def _rec(value, lo, hi, outcome, metric="confident_error_final", **kw):
    return {"comparison": "with_uncertainty-model_based", "method": "with_uncertainty", "baseline": "model_based",
            "metric": metric, "pooling": "mean", "value": value, "lo": lo, "hi": hi, "better": "lower",
            "outcome": outcome, "over": ["targets", "tracks"], "n": {"targets": 8, "tracks": 32}, **kw}


def _pop(primary_rec):
    fam = [_rec(-0.02, -0.05, 0.01, "not distinguishable", primary=True, family=2,
                outcome_holm="not distinguishable", lo_holm=-0.06, hi_holm=0.02),
           _rec(0.01, -0.01, 0.03, "not distinguishable", metric="correct_final", primary=True, family=2,
                outcome_holm="not distinguishable")]
    return {"records": fam, "n_targets": 8,
            "primary": {"comparison": "with_uncertainty-model_based", "metric": "confident_error_final",
                        "setting": "biased_randomized", "record": primary_rec, "adjusted": False}}


def test_the_primary_comes_first_with_its_own_interval_and_the_rest_is_exploratory():
    lines = bottom_line(_pop(_rec(-0.08, -0.12, -0.03, "better", primary=False)))   # as the engine writes it
    assert lines[0].startswith("Primary comparison (declared before the run in evaluate.primary")
    assert "−0.12" in lines[0] and "−0.03" in lines[0] and "better" in lines[0] and "not adjusted" in lines[0]
    assert "biased-plus-randomized" in lines[0] and "exploratory" not in lines[0]
    assert lines[1].startswith("Exploratory") and "separately from the primary comparison" in lines[1]


def test_a_primary_the_run_could_not_measure_says_so():
    pop = _pop(None)
    pop["primary"]["missing"] = "the run has no 'biased_randomized' setting"
    assert "not measured (the run has no 'biased_randomized' setting)" in primary_line(pop)
    assert primary_line({}) == ""
