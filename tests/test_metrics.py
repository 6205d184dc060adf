"""Metrics of the paper's §5.1 on small posteriors worked out by hand."""
import math
from typing import Mapping

import numpy as np
import pytest

from pipeline.evaluation import metrics as M
def summary_table(posteriors: Mapping[str, np.ndarray], truth, *, is_log: bool = False):
    """A pandas DataFrame, one row per method: ``posteriors`` maps method name -> (R, K, C)."""
    import pandas as pd

    rows = [{"method": name, **M.summary_row(p, truth, is_log=is_log)} for name, p in posteriors.items()]
    return pd.DataFrame(rows).set_index("method")


def test_single_posterior_by_hand():
    p = np.array([0.2, 0.5, 0.3])
    assert M.prob_truth(p, 1) == pytest.approx(0.5)
    # MSDE (Eq. 44): ((0.2)² + (0.5 - 1)² + (0.3)²) / 3
    assert M.msde(p, 1) == pytest.approx((0.04 + 0.25 + 0.09) / 3)
    assert M.msde(p, 0) == pytest.approx((0.64 + 0.25 + 0.09) / 3)
    assert M.log_mgr(p, 1) == 0.0                          # the truth is the most likely class
    assert M.log_mgr(p, 0) == pytest.approx(math.log(0.5 / 0.2))
    assert bool(M.correct(p, 1)) and not bool(M.correct(p, 2))
    # Log posteriors give the same numbers.
    lp = np.log(p)
    assert M.log_mgr(lp, 2, is_log=True) == pytest.approx(math.log(0.5 / 0.3))
    assert M.msde(lp, 1, is_log=True) == pytest.approx(M.msde(p, 1))


def test_log_mgr_underflow():
    # From probabilities an impossible truth is +inf; from log posteriors it stays finite.
    assert M.log_mgr(np.array([1.0, 0.0]), 1) == np.inf
    assert M.log_mgr(np.array([0.0, -900.0]), 1, is_log=True) == pytest.approx(900.0)


def test_track_ratios_and_table():
    # 2 realizations x 3 steps x 2 classes; truth = class 0.
    post = np.array([[[0.4, 0.6], [0.7, 0.3], [0.9, 0.1]],
                     [[0.8, 0.2], [0.45, 0.55], [0.3, 0.7]]])
    final, overall = M.correct_ratio(post, 0)
    assert final == pytest.approx(0.5) and overall == pytest.approx(3 / 6)
    tm = M.track_metrics(post, 0)
    np.testing.assert_allclose(tm["prob_truth"], post[..., 0])
    np.testing.assert_allclose(tm["log_mgr"][0], [math.log(0.6 / 0.4), 0.0, 0.0])
    # Per-realization truth.
    final, overall = M.correct_ratio(post, np.array([0, 1]))
    assert final == pytest.approx(1.0) and overall == pytest.approx((2 + 2) / 6)
    table = summary_table({"a": post, "b": post[:, :, ::-1]}, 0)
    assert list(table.index) == ["a", "b"]
    assert table.loc["a", "correct_final"] == pytest.approx(0.5)
    assert table.loc["b", "correct_overall"] == pytest.approx(3 / 6)
    final_mgr = np.array([0.0, math.log(0.7 / 0.3)])
    assert table.loc["a", "log_mgr_p75_final"] == pytest.approx(np.percentile(final_mgr, 75))
    assert table.loc["a", "prob_truth_final"] == pytest.approx(0.6)


def test_percentile_keeps_infinity():
    assert M.percentile([0.0, 1.0, np.inf, np.inf], 95) == np.inf
    assert M.percentile([0.0, 1.0, 2.0, np.inf], 50) == pytest.approx(1.5)


def test_bad_inputs():
    with pytest.raises(ValueError, match="out of range"):
        M.prob_truth(np.array([0.5, 0.5]), 2)
    with pytest.raises(ValueError, match="NaN"):
        M.msde(np.array([np.nan, 1.0]), 0)
    with pytest.raises(ValueError, match="integer"):
        M.correct(np.array([0.5, 0.5]), 0.5)
