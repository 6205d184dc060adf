"""The Student-t likelihood's cross-fitted degrees of freedom (``domain.tails``): each fold's ν from
the other folds' residuals only, and the domain-fit reading of a t on the Gaussian scale."""
import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.domain import fit as D
from pipeline.evaluation.domain import tails
from pipeline.method.names import MB_T, WU_T


def _table(z_by_scan: dict) -> tuple[pd.DataFrame, dict]:
    scans = np.concatenate([[s] * len(z) for s, z in z_by_scan.items()])
    z = np.concatenate(list(z_by_scan.values()))
    tab = pd.DataFrame({"scan": scans, "instance": "a", "component": 0, "obs": z, "mu": 0.0, "var": 1.0, "v_z": 0.0})
    return tab, {"gp": D.standardized(tab, "gp"), "gp_plus_dropout": D.standardized(tab, "gp_plus_dropout")}


def test_each_fold_takes_nu_from_the_other_folds_only():
    rng = np.random.default_rng(0)
    n = 6000
    tab, z = _table({"s1": rng.standard_t(2.0, n), "s2": rng.standard_normal(n), "s3": rng.standard_normal(n)})
    est = tails.cross_fit_df(tab, z, "scan", ["s1", "s2", "s3"])
    assert set(est) == {"s1", "s2", "s3"} and set(est["s1"]) == {WU_T, MB_T}
    # s1's heavy tail is in the other folds' estimates, never in its own
    assert est["s1"][MB_T] > 50 and est["s2"][MB_T] < 20 and est["s3"][MB_T] < 20
    assert est["s1"][WU_T] == est["s1"][MB_T]   # v_z = 0: the two kinds' residuals are the same


def test_a_fold_with_nothing_outside_gets_no_nu_and_its_rows_no_t_reading():
    rng = np.random.default_rng(1)
    tab, z = _table({"s1": rng.standard_normal(50)})
    est = tails.cross_fit_df(tab, z, "scan", ["s1"])
    assert est == {}
    g = tails.t_kinds(tab, z, "scan", est)
    assert set(g) == {"gp_t", "gp_plus_dropout_t"} and np.all(np.isnan(g["gp_t"]))
    assert D.fit_summary(g["gp_t"])["n"] == 0


def test_t_reading_covers_t_residuals():
    rng = np.random.default_rng(2)
    n = 20000
    tab, z = _table({"s1": rng.standard_t(3.0, n), "s2": rng.standard_t(3.0, n)})
    est = tails.cross_fit_df(tab, z, "scan", ["s1", "s2"])
    g = tails.t_kinds(tab, z, "scan", est)
    gauss, t = D.fit_summary(z["gp"]), D.fit_summary(g["gp_t"])
    # the Gaussian's 95 % interval covers t_3 residuals 85.5 %; the fitted t's its nominal 95 %
    assert gauss["coverage95"] == pytest.approx(0.855, abs=0.006)
    assert t["coverage95"] == pytest.approx(0.95, abs=0.006)
