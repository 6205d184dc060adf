"""Robust pooling: the median over targets resists one extreme target; leave-one-target-out."""
import numpy as np

from pipeline.evaluation.statistics import robust as R
from pipeline.evaluation.statistics.popstats import hierarchical


def _groups(seed=0):
    rng = np.random.default_rng(seed)
    return [rng.normal(1.0 + 0.1 * t, 0.5, size=4 + t % 3) for t in range(12)]


def test_median_unmoved_by_one_target_times_1e6_while_the_mean_moves():
    g = _groups()
    top = int(np.argmax([x.mean() for x in g]))          # the target that carries the mean (as mahatma_rice)
    big = [x * 1e6 if i == top else x for i, x in enumerate(g)]
    med, med_big = R.pooled(g, 500, 0), R.pooled(big, 500, 0)
    assert med["value"] == med_big["value"]
    mean, mean_big = hierarchical(g, 500, 0), hierarchical(big, 500, 0)
    assert abs(mean_big["value"] - mean["value"]) > 1e4
    assert med_big["ci_high"] < 10  # the extreme target stays out of the CI as well


def test_any_one_target_moves_the_median_at_most_one_order_statistic():
    g = _groups()
    means = np.sort([x.mean() for x in g])
    for i in range(len(g)):
        v = R.pooled([x * 1e6 if j == i else x for j, x in enumerate(g)], 100, 0)["value"]
        assert means[4] <= v <= means[7]


def test_resample_slot_means_and_member_weights_agree():
    g = _groups(1)
    rs = R.Resample([len(x) for x in g], 50, 3)
    P = R.pad(g)
    means = rs.slot_means(P).mean(axis=1)
    w = rs.member_weights()
    assert np.allclose(w.sum(axis=(1, 2)), 1.0)
    assert np.allclose(np.einsum("btj,tj->b", w, P), means)
    # the mean statistic has the same value as popstats' hierarchical bootstrap
    assert R.pooled(g, 200, 0, "mean")["value"] == hierarchical(g, 200, 0)["value"]


def test_leave_one_out_reports_range_and_flips():
    g = [np.array([0.1, 0.2])] * 2 + [np.array([5.0, 6.0])] * 1 + [np.array([-0.01, 0.01])] * 2
    out = R.leave_one_out(list("abcde"), g, 300, 0, "mean", True)
    assert out["loto_min"] < out["loto_max"]
    assert out["outcome"] in ("better", "not distinguishable")
    strong = [np.array([1.0, 1.1, 0.9])] * 6
    assert R.leave_one_out(list("abcdef"), strong, 300, 0, "median", True)["loto_flips"] == []
