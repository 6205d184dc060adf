"""Holm over the declared primary family: bootstrap p-values, the adjusted p-values, and the
step-down by widened intervals on a planted family whose p-values are known."""
import numpy as np
import pandas as pd
import pytest
from scipy.stats import norm

from pipeline.evaluation.metrics.labels import in_primary_family
from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.engine import population_block
from pipeline.evaluation.statistics.multiplicity import adjusted, bootstrap_p, holm, holm_p

B = 40_000
WU_MB, WU_SB = "with_uncertainty-model_based", "with_uncertainty-simple_bayes"


def planted(p_two_sided: float) -> np.ndarray:
    """Draws of a difference whose two-sided bootstrap p-value of 0 is ``p_two_sided`` (normal,
    evenly spaced quantiles: no sampling noise)."""
    mu = -norm.ppf(p_two_sided / 2)
    return mu + norm.ppf((np.arange(B) + 0.5) / B)


def test_bootstrap_p_counts_both_sides_with_the_plus_one_correction():
    d = np.array([-1.0, 0.0, 1.0, 2.0, 3.0])
    assert bootstrap_p(d) == pytest.approx(2 * (1 + 2) / 6)
    assert bootstrap_p(np.ones(99)) == pytest.approx(2 / 100)          # never 0
    assert bootstrap_p(None) == 1.0 and bootstrap_p(np.array([1.0, np.nan])) == 1.0
    assert bootstrap_p(planted(0.02)) == pytest.approx(0.02, abs=2e-4)


def test_holm_adjusted_p_values_on_a_known_family():
    # sorted 0.001, 0.02, 0.03, 0.3 of 4: 0.004, 0.06, 0.06 (monotone), 0.3
    assert holm_p([0.03, 0.001, 0.3, 0.02]) == pytest.approx([0.06, 0.004, 0.3, 0.06])


def _records(ps, metrics=("correct_final", "confident_error_final")):
    recs, draws = [], {}
    keys = [(c, m) for c in (WU_MB, WU_SB) for m in metrics]
    for (c, m), p in zip(keys, ps):
        d = planted(p) * (1 if m == "correct_final" else -1)       # lower confident errors are better
        est = {"value": float(np.median(d)), "ci_low": np.percentile(d, 2.5), "ci_high": np.percentile(d, 97.5)}
        recs.append(REC.record(c, m, est, pooling="mean", better="higher" if m == "correct_final" else "lower",
                               over=["targets", "tracks"], n={"targets": 10}, primary=True))
        draws[(c, m)] = d
    return recs, draws


def test_the_step_down_keeps_only_what_survives_holm_and_never_contradicts_its_interval():
    recs, draws = _records([0.001, 0.02, 0.03, 0.3])
    holm(recs, draws)
    assert [r["outcome"] for r in recs] == ["better"] * 3 + ["not distinguishable"]
    # Holm: 4 x 0.001 = 0.004 rejects; 3 x 0.02 = 0.06 stops: only the first survives
    assert [r["outcome_holm"] for r in recs] == ["better"] + ["not distinguishable"] * 3
    assert [r["p_holm"] for r in recs] == pytest.approx([0.004, 0.06, 0.06, 0.3], abs=1e-3)
    assert recs[0]["level_holm"] == pytest.approx(1 - 0.05 / 4)
    assert all(r["level_holm"] == pytest.approx(1 - 0.05 / 3) for r in recs[1:])
    for r in recs:
        assert r["family"] == 4 and adjusted(r) == r["outcome_holm"]
        assert r["outcome_holm"] == REC.outcome(r["lo_holm"], r["hi_holm"], r["better"] == "higher")
        assert r["lo_holm"] <= r["lo"] and r["hi_holm"] >= r["hi"]         # wider than the unadjusted


def test_a_family_that_clears_every_step_keeps_every_verdict():
    recs, draws = _records([0.001, 0.015, 0.02, 0.004])   # 4x0.001, 3x0.004, 2x0.015, 1x0.02: all <= 0.05
    holm(recs, draws)
    assert [r["outcome_holm"] for r in recs] == [r["outcome"] for r in recs] == ["better"] * 4
    assert sorted(r["level_holm"] for r in recs) == pytest.approx(sorted(1 - 0.05 / k for k in (4, 3, 2, 1)))


def test_the_engine_adjusts_the_primary_family_only():
    rng = np.random.default_rng(0)
    rows = []
    for t in range(8):
        for j in range(3):
            base = rng.normal(0.5, 0.1)
            for m, shift in (("with_uncertainty", 0.04), ("model_based", 0.0), ("simple_bayes", 0.02)):
                v = base + shift + rng.normal(0, 0.02)
                rows.append({"target": f"t{t}", "track": j, "setting": "x", "method": m, "correct_final": v,
                             "prob_truth_final": v})
    cells = pd.DataFrame(rows)
    comps = [("with_uncertainty", "model_based"), ("with_uncertainty", "simple_bayes"), ("simple_bayes", "model_based")]
    b = population_block(cells, ["with_uncertainty", "model_based", "simple_bayes"],
                         ["correct_final", "prob_truth_final"], comps, 500, 0, primary=("correct_final",), loto=False)
    fam = [r for r in b["records"] if "outcome_holm" in r]
    assert {(r["comparison"], r["metric"]) for r in fam} == {(WU_MB, "correct_final"), (WU_SB, "correct_final")}
    assert all(in_primary_family(r["comparison"], r["primary"]) for r in fam) and all(r["family"] == 2 for r in fam)
    others = [r for r in b["records"] if r not in fam]
    assert others and all(adjusted(r) == r["outcome"] for r in others)


def test_design_t_statistics_step_down_on_their_own_p_values_at_full_resolution():
    # records whose intervals come from the design (a t statistic): p from t, no bootstrap tail draws;
    # each adjusted interval is the t interval at its Holm level, so the verdict and interval agree
    from scipy.stats import t as student_t

    from pipeline.evaluation.statistics.design import TStat

    df, se = 9.0, 0.01
    ps = [0.0004, 0.011, 0.02, 0.4]
    recs, stats = [], {}
    for (c, m), p in zip([(c, m) for c in (WU_MB, WU_SB) for m in ("correct_final", "prob_truth_final")], ps):
        value = student_t.isf(p / 2, df) * se
        ts = TStat(value, se, df)
        assert ts.p() == pytest.approx(p, rel=1e-9)
        e = ts.estimate()
        recs.append(REC.record(c, m, e, pooling="mean", better="higher", over=["targets", "tracks"],
                               n={"targets": 10}, primary=True))
        stats[(c, m)] = ts
    holm(recs, stats, family=lambda comp, primary: True)
    # Holm: 4 x 0.0004 rejects, 3 x 0.011 = 0.033 rejects, 2 x 0.02 = 0.04 rejects, 0.4 stops
    assert [r["outcome_holm"] for r in recs] == ["better"] * 3 + ["not distinguishable"]
    assert [r["p_holm"] for r in recs] == pytest.approx(holm_p(ps), rel=1e-9)
    for r, k in zip(recs, (4, 3, 2, 1)):
        assert r["level_holm"] == pytest.approx(1 - 0.05 / k)
        half = student_t.ppf(0.5 + r["level_holm"] / 2, df) * se
        assert (r["lo_holm"], r["hi_holm"]) == pytest.approx((r["value"] - half, r["value"] + half), rel=1e-9)
        assert r["outcome_holm"] == REC.outcome(r["lo_holm"], r["hi_holm"], True)


def test_a_withheld_record_is_no_verdict_and_stays_out_of_the_family():
    from pipeline.evaluation.statistics.design import TStat

    e = {"value": 0.3, "ci_low": float("nan"), "ci_high": float("nan")}
    rec = REC.record(WU_MB, "msde_final", e, pooling="mean", better="lower", over=["targets", "tracks"],
                     n={"targets": 12, "scans": 2}, primary=True, withheld="2 scans: too few")
    assert rec["outcome"] == "withheld" and REC.consistent(rec)
    assert not REC.consistent({**rec, "outcome": "not distinguishable"})
    recs, draws = _records([0.001, 0.02])
    holm([rec, *recs], {**draws, (WU_MB, "msde_final"): TStat(0.3, 0.001, 1.0, withheld="2 scans")})
    # never tested: no p, no adjusted verdict, and the family is the two records that were tested
    assert "outcome_holm" not in rec and "p" not in rec and "family" not in rec
    assert all(r["family"] == 2 for r in recs)


def test_the_declared_primary_pair_leaves_the_exploratory_family():
    # the declared comparison is tested alone at 0.05 (grid.primary): its record in a block of the
    # same cells is marked declared, keeps its own verdict, and the family shrinks by one
    recs, draws = _records([0.001, 0.02, 0.03, 0.3])
    holm(recs, draws, exclude={(WU_MB, "correct_final")})
    assert recs[0]["declared"] and "outcome_holm" not in recs[0] and adjusted(recs[0]) == recs[0]["outcome"]
    assert all(r["family"] == 3 and not r.get("declared") for r in recs[1:])
    # Holm over the other three: 3 x 0.02 = 0.06 stops, where with the pair inside it was the same step
    assert [r["p_holm"] for r in recs[1:]] == pytest.approx(holm_p([0.02, 0.03, 0.3]), abs=1e-3)
