"""The metric specification (pipeline.evaluation.metrics.spec) on small posteriors worked out by hand."""
import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics import spec as M
from tests.support.params import PARAMS


def test_single_posterior_by_hand():
    p = np.array([0.2, 0.5, 0.3])
    assert M.prob_truth(p, 1) == pytest.approx(0.5)
    # MSDE (Eq. 44): ((0.2)² + (0.5 - 1)² + (0.3)²) / 3
    assert M.msde(p, 1) == pytest.approx((0.04 + 0.25 + 0.09) / 3)
    assert M.msde(p, 0) == pytest.approx((0.64 + 0.25 + 0.09) / 3)
    assert M.log10_mgr(p, 1) == 0.0                        # the truth is the most likely class
    assert M.log10_mgr(p, 0) == pytest.approx(math.log10(0.5 / 0.2))
    assert bool(M.correct(p, 1)) and not bool(M.correct(p, 2))
    # Log posteriors give the same numbers.
    lp = np.log(p)
    assert M.log10_mgr(lp, 2, is_log=True) == pytest.approx(math.log10(0.5 / 0.3))
    assert M.msde(lp, 1, is_log=True) == pytest.approx(M.msde(p, 1))
    assert list(M.step_values(p, 0)) == list(M.STEP_COLUMNS)


def test_log_mgr_underflow():
    # From probabilities an impossible truth is +inf; from log posteriors it stays finite.
    assert M.log10_mgr(np.array([1.0, 0.0]), 1) == np.inf
    assert M.log10_mgr(np.array([0.0, -900.0]), 1, is_log=True) == pytest.approx(900.0 / math.log(10))


def test_every_metric_of_a_small_track():
    # 2 realizations x 3 steps x 2 classes; truth = class 0.
    post = np.array([[[0.4, 0.6], [0.7, 0.3], [0.9, 0.1]],
                     [[0.8, 0.2], [0.45, 0.55], [0.3, 0.7]]])
    m = M.posterior_metrics(post, 0, params=PARAMS)
    assert list(m) == list(M.METRICS)
    assert m["correct_final"] == pytest.approx(0.5) and m["correct_overall"] == pytest.approx(3 / 6)
    assert m["prob_truth_final"] == pytest.approx(0.6)
    assert m["msde_final"] == pytest.approx((0.01 + 0.49) / 2)
    final = np.log10([1.0, 0.7 / 0.3])
    assert m["log10_mgr75_final"] == pytest.approx(np.percentile(final, 75))
    every = np.log10(post.max(-1) / post[..., 0]).ravel()
    assert m["log10_mgr95_overall"] == pytest.approx(np.percentile(every, 95))
    # Log posteriors and probabilities agree, and so does the long-table route.
    lm = M.posterior_metrics(np.log(post), 0, params=PARAMS, is_log=True)
    assert lm == pytest.approx(m)
    sv = M.step_values(post, 0)
    rows = pd.DataFrame({"realization": np.repeat([0, 1], 3), "step": np.tile([0, 1, 2], 2),
                         **{k: v.ravel() for k, v in sv.items()}}).sample(frac=1.0, random_state=0)
    assert M.scalars(M.matrices(rows), params=PARAMS) == pytest.approx(m)


def test_compute_vectorizes_over_leading_axes():
    rng = np.random.default_rng(0)
    post = rng.dirichlet(np.ones(3), size=(4, 5, 6))            # 4 groups x R=5 x K=6
    sv = M.step_values(post, 1)
    batch = M.compute(sv, params=PARAMS)
    for g in range(4):
        one = M.posterior_metrics(post[g], 1, params=PARAMS)
        assert {k: float(v[g]) for k, v in batch.items()} == pytest.approx(one)


def test_percentile_keeps_infinity():
    # Interpolating toward an infinite value is infinite (the issue's [0, 1, 2, inf] example).
    assert M.percentile([0.0, 1.0, 2.0, np.inf], 95) == np.inf
    assert M.percentile([0.0, 1.0, np.inf, np.inf], 95) == np.inf
    assert M.percentile([0.0, 1.0, 2.0, np.inf], 50) == pytest.approx(1.5)
    rows = np.array([[0.0, 1.0, 2.0, np.inf], [0.0, 1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(M.percentile(rows, 95, axis=-1), [np.inf, np.percentile(rows[1], 95)])
    assert np.isnan(M.percentile([], 50))


def test_one_infinity_rule_for_percentiles_and_intervals():
    """-inf is a value like +inf, a NaN entry makes its slice NaN, and the engine's interval is this
    percentile at 2.5 and 97.5 (the same numbers, one rule)."""
    from pipeline.evaluation.statistics.resampler import interval

    assert M.percentile([-np.inf, 0.0, 1.0, 2.0], 5) == -np.inf
    assert M.percentile([-np.inf, 0.0, 1.0, 2.0], 50) == pytest.approx(0.5)
    assert np.isnan(M.percentile([0.0, np.nan, 1.0], 50))
    draws = np.random.default_rng(3).normal(size=(3, 400))
    draws[1, :30] = np.inf
    draws[2, -30:] = -np.inf
    lo, hi = interval(draws)
    np.testing.assert_array_equal(lo, M.percentile(draws, 2.5, axis=-1))
    np.testing.assert_array_equal(hi, M.percentile(draws, 97.5, axis=-1))
    np.testing.assert_array_equal(lo[0], np.percentile(draws[0], 2.5))     # finite draws: numpy's own
    assert hi[1] == np.inf and lo[2] == -np.inf


def test_metric_metadata():
    for k, m in M.METRICS.items():
        cols = (m.column,) if isinstance(m.column, str) else m.column
        assert set(cols) <= set(M.STEP_COLUMNS) and m.steps in ("final", "all") and m.pool in M.POOLS, k
        assert M.metric_label(k) == m.label and M.metric_label(k, short=True) == m.short
    assert M.METRICS["correct_final"].bounded and not M.METRICS["log10_mgr95_final"].bounded
    assert not M.higher_is_better("msde_final") and M.higher_is_better("correct_overall")
    assert M.metric_label("not_a_metric") == "not_a_metric"


def test_adding_a_metric_is_one_entry(request):
    request.addfinalizer(lambda: [M.unregister_metric(k) for k in ("prob_truth_overall", "wrong_unsure")])
    extra = dataclasses.replace(M.METRICS["prob_truth_final"], label="P(truth), all steps", steps="all")
    M.register_metric("prob_truth_overall", extra)
    assert list(M.METRICS)[-1] == "prob_truth_overall" and not M.METRICS.is_builtin("prob_truth_overall")
    post = np.array([[[0.4, 0.6], [0.7, 0.3]]])
    assert M.posterior_metrics(post, 0, params=PARAMS)["prob_truth_overall"] == pytest.approx(0.55)
    # A metric of two per-step columns: the share of steps that are wrong with P(truth) < 0.5.
    two = M.Metric("wrong and unsure", "wrong, unsure", False, ("correct", "p_truth"), "all",
                   lambda ok, p, params: ((ok == 0) & (p < 0.5)).mean(axis=-1), best=0.0, worst=1.0)
    M.register_metric("wrong_unsure", two)
    with pytest.raises(ValueError, match=r"metric 'wrong_unsure' \(register\): registered twice"):
        M.register_metric("wrong_unsure", extra)
    with pytest.raises(ValueError, match=r"column\(s\) \['nope'\]"):
        M.register_metric("bad", dataclasses.replace(extra, column="nope"))
    assert M.posterior_metrics(post, 0, params=PARAMS)["wrong_unsure"] == pytest.approx(0.5)
    batch = M.compute(M.step_values(np.stack([post, post[..., ::-1]]), 0), ["wrong_unsure"], params=PARAMS)
    np.testing.assert_allclose(batch["wrong_unsure"], [0.5, 0.5])


def test_mgr_ratios_beside_log10():
    r = M.with_mgr_ratios({"correct_final": 1.0, "log10_mgr95_final": 2.0, "log10_mgr75_final": 400.0,
                           "log10_mgr95_overall": np.inf})
    assert r["mgr95_final"] == pytest.approx(100.0) and r["log10_mgr95_final"] == 2.0
    assert r["mgr75_final"] is None and r["log10_mgr75_final"] == 400.0   # overflows float64 as a ratio
    assert r["mgr95_overall"] is None and r["log10_mgr95_overall"] is None
    assert r["correct_final"] == 1.0


def test_bad_inputs():
    with pytest.raises(ValueError, match="out of range"):
        M.prob_truth(np.array([0.5, 0.5]), 2)
    with pytest.raises(ValueError, match="NaN"):
        M.msde(np.array([np.nan, 1.0]), 0)
    with pytest.raises(ValueError, match="integer"):
        M.correct(np.array([0.5, 0.5]), 0.5)
