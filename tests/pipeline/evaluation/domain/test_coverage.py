"""The pooled coverage's CI (pipeline/evaluation/domain/coverage.py): clustered by the run's units,
withheld under 8 units of a level, and the same ratio as the share it goes with."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pipeline.evaluation.domain.coverage import coverage_cis
from pipeline.evaluation.domain.fit import fit_summary
from pipeline.evaluation.statistics.resampler import wilson_interval

N_INST, PER, REPS, MEAN = 20, 100, 200, 0.95


def _table(rng, n_inst: int = N_INST, scans: int = 1, per: int = PER) -> tuple[pd.DataFrame, np.ndarray]:
    """Residuals of ``n_inst`` instances seen in ``scans`` scans each: instance i's residuals fall
    inside ±1.96 with its own probability p_i ~ Beta(19, 1) (mean 0.95), the clustered structure a
    crop table has (one instance's crops share its model's misfit)."""
    p = rng.beta(19.0, 1.0, n_inst)
    rows = []
    for i in range(n_inst):
        for s in range(scans):
            inside = rng.random(per) < p[i]
            rows.append(pd.DataFrame({"scan": f"s{(i + s) % max(scans, 1):02d}" if scans > 1 else "s00",
                                      "instance": f"i{i:02d}", "z": np.where(inside, 0.0, 3.0)}))
    t = pd.concat(rows, ignore_index=True)
    return t, t["z"].to_numpy(float)


def test_the_clustered_ci_covers_the_truth_where_a_per_residual_interval_does_not():
    # Equal cluster sizes: the population's pooled coverage is E[p_i] = 0.95 exactly. A per-residual
    # (Wilson) interval ignores the instances' spread (sd of p_i 0.048 against a binomial sd of
    # 0.005 over 2000 residuals), so it covers about P(|N| < 0.84) ~ 0.6; the instances' bootstrap
    # ~ 0.93 at 20 instances. 200 replications: binomial MC sd <= sqrt(0.93 * 0.07 / 200) = 0.018,
    # so >= 0.88 is 2.8 sd under 0.93; the naive bound 0.80 is 5 sd over 0.6 (sd 0.035).
    clustered = naive = 0
    for r in range(REPS):
        t, z = _table(np.random.default_rng([11, r]))
        lo, hi = coverage_cis(t, {"gp": z}, "target", 1000, r)["gp"]["coverage95_ci"]
        clustered += lo <= MEAN <= hi
        k = int(np.sum(np.abs(z) <= 1.96))
        a, b = wilson_interval(k, len(z))
        naive += a <= MEAN <= b
    assert clustered / REPS >= 0.88, clustered
    assert naive / REPS <= 0.80 and naive < clustered, (naive, clustered)


def test_the_interval_holds_the_share_and_says_what_it_resamples():
    t, z = _table(np.random.default_rng(1), scans=9)
    share = fit_summary(z)["coverage95"]
    for cluster, over, units in (("target", "instances, then the scans each was seen in", {"instances": 20}),
                                 ("scan", "scans, then the instances in each", {"instances": 20, "scans": 9}),
                                 ("crossed", "instances and scans, crossed", {"instances": 20, "scans": 9})):
        e = coverage_cis(t, {"gp": z, "gp_t": -z}, cluster, 500, 3)
        assert e["gp"]["coverage95_over"] == over and e["gp"]["coverage95_units"] == units
        lo, hi = e["gp"]["coverage95_ci"]
        assert lo <= share <= hi and hi - lo > 0 and "coverage95_withheld" not in e["gp"]
        assert e["gp_t"]["coverage95_ci"] == [lo, hi]          # |z| alike: the same draws give the same CI
    # one scan: the scans level has nothing to vary over, so the instances carry the interval
    t, z = _table(np.random.default_rng(2))
    one = coverage_cis(t, {"gp": z}, "scan", 500, 3)["gp"]
    assert one["coverage95_over"] == "instances, then the scans each was seen in"
    assert one["coverage95_units"] == {"instances": 20} and one["coverage95_ci"] is not None


def test_under_eight_units_of_a_level_there_is_no_ci_and_it_says_why():
    t, z = _table(np.random.default_rng(4), n_inst=7)
    e = coverage_cis(t, {"gp": z}, "target", 500, 0)["gp"]
    assert e["coverage95_ci"] is None and e["coverage95_withheld"].startswith("7 instances: ")
    t, z = _table(np.random.default_rng(5), n_inst=12, scans=5)   # enough instances, 5 scans
    e = coverage_cis(t, {"gp": z}, "scan", 500, 0)["gp"]
    assert e["coverage95_ci"] is None and e["coverage95_withheld"].startswith("5 scans: ")
    e = coverage_cis(t, {"gp": z}, "target", 500, 0)["gp"]   # clustered on instances, the scans do not count
    assert e["coverage95_ci"] is not None and "coverage95_withheld" not in e


def test_non_finite_residuals_count_in_neither_the_share_nor_its_draws():
    t, z = _table(np.random.default_rng(6))
    z = z.copy()
    z[::7] = np.nan
    lo, hi = coverage_cis(t, {"gp": z}, "target", 500, 0)["gp"]["coverage95_ci"]
    assert math.isfinite(lo) and math.isfinite(hi) and lo <= fit_summary(z)["coverage95"] <= hi


def test_a_resample_that_keeps_no_residual_leaves_no_interval_and_says_so(monkeypatch):
    from pipeline.evaluation.domain import coverage

    t, z = _table(np.random.default_rng(7))
    real = coverage._weights

    def one_empty(*a):   # the first draw keeps no cluster (as a crossed draw can)
        w, over = real(*a)
        w = w.copy()
        w[0] = 0.0
        return w, over

    monkeypatch.setattr(coverage, "_weights", one_empty)
    e = coverage_cis(t, {"gp": z}, "target", 500, 0)["gp"]
    assert e["coverage95_ci"] is None and "undefined" in e["coverage95_withheld"]
