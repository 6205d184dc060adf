"""Calibration metrics on hand-computed cases: NLL, MSDE (the Brier score / C) and confident errors
from the one metric spec, top-label ECE from the binning module."""
import math

import numpy as np
import pytest

from pipeline.evaluation.metrics import calibration as K
from pipeline.evaluation.metrics import spec as M


def test_nll_msde_confident_error_hand_values():
    p = np.array([[0.7, 0.2, 0.1], [0.1, 0.3, 0.6], [0.995, 0.004, 0.001]])
    lp = np.log(p)
    t = np.array([0, 1, 1])
    assert np.allclose(M.nll(lp, t, is_log=True), [-math.log(0.7), -math.log(0.3), -math.log(0.004)])
    brier = [0.3**2 + 0.04 + 0.01, 0.01 + 0.49 + 0.36, 0.995**2 + 0.996**2 + 1e-6]   # Σ_c (P(c) - 1[c = t])²
    assert np.allclose(3 * M.msde(lp, t, is_log=True), brier)                          # MSDE = Brier / C
    conf, ok = K.top_label(lp, t)
    assert M.confident_mask(conf, ok, 0.99).tolist() == [False, False, True]
    assert M.confident_errors(lp, t, 0.99).tolist() == [False, False, True]
    assert M.confident_mask(conf, ok, 0.999).tolist() == [False, False, False]


def test_nll_from_log_posteriors_stays_finite_where_probabilities_underflow():
    lp = np.array([0.0, -7000.0])  # P(truth) = e^-7000: 0.0 as a float64 probability
    assert M.nll(lp, 1, is_log=True) == pytest.approx(7000.0)
    assert np.isfinite(M.nll(lp, 1, is_log=True))


def test_ece_hand_value_and_bins():
    # confidences 0.9 (2 right, 1 wrong), 0.6 (1 wrong), 1.0 (1 right, 1 wrong): 15 bins
    conf = np.array([0.9, 0.9, 0.9, 0.6, 1.0, 1.0])
    ok = np.array([1, 1, 0, 0, 1, 0], bool)
    want = (3 / 6) * abs(2 / 3 - 0.9) + (1 / 6) * abs(0 - 0.6) + (2 / 6) * abs(0.5 - 1.0)
    assert K.ece(conf, ok) == pytest.approx(want)
    # bin index as torchmetrics' bucketize(right=True) - 1: 1.0 has a bin of its own, 14/15 starts bin 14
    assert K.bin_index(np.array([0.0, 1 / 15 - 1e-9, 0.5, 14 / 15 + 1e-12, 1.0])).tolist() == [0, 0, 7, 14, 15]


def test_weighted_ece_equals_repeated_posteriors():
    conf = np.array([0.55, 0.8, 0.95])
    ok = np.array([1, 0, 1], bool)
    w = np.array([2.0, 1.0, 3.0])
    rep = K.ece(np.repeat(conf, [2, 1, 3]), np.repeat(ok, [2, 1, 3]))
    assert K.ece(conf, ok, w) == pytest.approx(rep)


def test_calibrated_posterior_has_ece_near_zero_and_constant_overconfidence_its_gap():
    rng = np.random.default_rng(0)
    n, C = 200_000, 4
    conf = rng.uniform(0.25, 1.0, n)
    ok = rng.random(n) < conf                       # right with probability = its confidence
    assert K.ece(conf, ok) < 0.01
    # a constant 0.99 that is right 60 % of the time: ECE = 0.99 - 0.6
    p = np.full((n, C), 0.01 / 3)
    t = np.where(rng.random(n) < 0.6, 0, 1)
    p[:, 0] = 0.99
    conf2, ok2 = K.top_label(np.log(p), t)
    assert K.ece(conf2, ok2) == pytest.approx(0.99 - ok2.mean(), abs=1e-9)
    assert abs(ok2.mean() - 0.6) < 0.01


def test_ece_from_sums_of_parts_is_the_ece_of_the_union():
    rng = np.random.default_rng(1)
    c1, c2 = rng.uniform(0, 1, 50), rng.uniform(0, 1, 70)
    o1, o2 = rng.random(50) < 0.5, rng.random(70) < 0.7
    whole = K.ece(np.concatenate([c1, c2]), np.concatenate([o1, o2]))
    assert K.ece_from_sums(K.bin_sums(c1, o1) + K.bin_sums(c2, o2)) == pytest.approx(whole)
    rel = K.reliability(K.bin_sums(c1, o1))
    assert len(rel["share"]) == 16 and sum(s for s in rel["share"] if s) == pytest.approx(1.0)


def test_cell_calibration_metrics_final_and_overall_at_the_given_threshold():
    lp = np.log(np.array([[[0.5, 0.5], [0.995, 0.005]]]))   # R=1, K=2, C=2, truth 1
    out = M.posterior_metrics(lp, 1, params=M.Params(0.99, 15), is_log=True)
    assert out["nll_final"] == pytest.approx(-math.log(0.005))
    assert out["nll_overall"] == pytest.approx((-math.log(0.5) - math.log(0.005)) / 2)
    assert out["confident_error_final"] == 1.0 and out["confident_error_overall"] == 0.5
    # a threshold above the top confidence: no confident error (the threshold is a parameter, not 0.99)
    assert M.posterior_metrics(lp, 1, params=M.Params(0.999, 15), is_log=True)["confident_error_final"] == 0.0
    with pytest.raises(ValueError, match="threshold"):
        M.Params(1.5, 15)
