"""The wild cluster bootstrap-t (pipeline/evaluation/statistics/wild.py): its closed-form draws equal
the literal bootstrap (rebuild y*, recompute the design's t), its weights have the moments they
claim, and the interval and the p-value it gives read the same order statistic."""
import math

import numpy as np
import pytest
from scipy.stats import t as student_t

from pipeline.evaluation.statistics import design as D
from pipeline.evaluation.statistics import wild
from pipeline.evaluation.statistics.design import TStat


def _layout(rng, n_obj, n_scan, tracks, nested=False):
    obj = np.repeat(np.arange(n_obj * n_scan if nested else n_obj), tracks * (1 if nested else n_scan))
    scan = (obj // n_obj) if nested else np.tile(np.repeat(np.arange(n_scan), tracks), n_obj)
    w = rng.random(len(obj)) + 0.5
    return D.Layout(w / w.sum(), {"targets": obj, "scans": scan, "categories": np.zeros(len(obj), int)})


@pytest.mark.parametrize("n_obj,n_scan,tracks,nested", [(12, 8, 2, False), (9, 14, 1, False), (10, 1, 3, False),
                                                        (4, 8, 2, True)])
def test_the_closed_form_draws_are_the_literal_wild_bootstrap(n_obj, n_scan, tracks, nested):
    rng = np.random.default_rng(n_obj * n_scan)
    layout = _layout(rng, n_obj, n_scan, tracks, nested)
    y = (rng.random((3, len(layout.weights))) < 0.2).astype(float) - (rng.random((3, len(layout.weights))) < 0.2)
    ref = wild.abs_t(y, layout, 64, (5,))
    lvl = wild.level(layout)
    assert lvl == min(layout.levels(), key=lambda k: (layout.levels()[k], k))
    cw = np.unique(layout.labels[lvl], return_inverse=True)[1]
    v = wild.weights(int(cw.max()) + 1, 64, (5,))
    theta = y @ layout.weights
    for b in range(64):                                   # literal: the bootstrap sample, the design's own variance
        ys = theta[:, None] + v[b][cw][None, :] * (y - theta[:, None])
        tb, Vb, _ = D.variance(ys, layout)
        assert np.abs(tb - theta) / np.sqrt(Vb) == pytest.approx(ref[:, b], rel=1e-9, abs=1e-12)


def test_the_weights_have_mean_zero_and_variance_one_and_webb_takes_few_units():
    few, many = wild.weights(8, 20000, (1,)), wild.weights(20, 20000, (1,))
    assert set(np.round(np.unique(few) ** 2, 12)) == {0.5, 1.0, 1.5}                 # Webb's six points
    assert set(np.unique(many)) == {-1.0, 1.0}                                       # Rademacher
    for v in (few, many):
        assert abs(v.mean()) < 4 / math.sqrt(v.size) and abs((v ** 2).mean() - 1) < 6 / math.sqrt(v.size)


def test_an_interval_at_one_minus_a_excludes_zero_exactly_when_p_is_at_most_a():
    rng = np.random.default_rng(2)
    ref = np.abs(rng.standard_t(4, 1999))
    for t in np.linspace(0.5, 6, 23):
        ts = TStat(t * 0.01, 0.01, 9.0, ref=ref)
        for level in (0.95, 1 - 0.05 / 3, 1 - 0.05 / 8, 0.999):
            e = ts.estimate(level)
            assert (e["ci_low"] > 0) == (ts.p() <= 1 - level + 1e-12), (t, level)
    # the multiplier is the larger of the reference's order statistic and t_df's quantile
    order = np.sort(ref)[math.ceil(0.95 * 2000) - 1]
    assert TStat(0.0, 1.0, 9.0, ref=ref).q() == pytest.approx(max(order, student_t.ppf(0.975, 9)))
    assert TStat(0.0, 1.0, 2.0, ref=ref).q() == pytest.approx(student_t.ppf(0.975, 2))     # t_2's is wider


def test_the_engine_statistic_reads_the_reference():
    rng = np.random.default_rng(4)
    layout = _layout(rng, 12, 8, 2)
    y = rng.standard_normal(len(layout.weights)) * 0.3 + 0.05
    est, ts = D.estimate(y, layout, n_boot=499, seed=0)
    again, _ = D.estimate(y, layout, n_boot=499, seed=0)
    assert est == again and est["interval"] == D.INTERVAL and ts.ref.shape == (499,)
    assert (est["ci_high"] - est["value"]) == pytest.approx(ts.q() * est["se"], rel=1e-12)
    plain, tp = D.estimate(y, layout)
    assert plain["interval"] == D.T_INTERVAL and tp.ref is None and plain["se"] == est["se"]


@pytest.mark.parametrize("n_obj,n_scan,tracks", [(12, 8, 2), (9, 14, 1), (15, 1, 2)])
def test_one_population_chunked_equals_the_replications_path(n_obj, n_scan, tracks, monkeypatch):
    # the engine's route (one population, sparse unit sums, draws read in chunks) and the suite's
    # (many replications, quadratic forms in the weights) give the same |t*|, draw by draw
    rng = np.random.default_rng(7)
    layout = _layout(rng, n_obj, n_scan, tracks)
    y = (rng.random((2, len(layout.weights))) < 0.3).astype(float) - (rng.random((2, len(layout.weights))) < 0.3)
    many = wild.abs_t(y, layout, 300, (1,))
    monkeypatch.setattr(wild, "CHUNK", 128)              # three chunks, the last one partial
    for up_to in (1000, 0):                              # the quadratic forms, then the sparse unit sums
        monkeypatch.setattr(wild, "QUADRATIC_UP_TO", up_to)
        for r in range(2):
            one = wild.abs_t(y[r:r + 1], layout, 300, (1,))
            assert one[0] == pytest.approx(many[r], rel=1e-9, abs=1e-12)
