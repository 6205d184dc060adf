"""The scan level of the one resampler (scans -> targets -> tracks)."""
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.engine import Hierarchy, population_block

AB = [("a", "b")]
METRIC = "correct_final"


def scans_population(rng, n_scans=5, targets=3, tracks=2, scan_sd=0.2, target_sd=0.02, effect=0.0,
                     diff_scan_sd=0.0):
    """Cells of ``n_scans`` scans, each with its own targets; a scan effect shared by its targets
    (``scan_sd``), a small target effect; method 'a' is ``effect`` higher, plus a per-scan
    difference effect (``diff_scan_sd``)."""
    rows = []
    for s in range(n_scans):
        se, de = rng.normal(0, scan_sd), rng.normal(0, diff_scan_sd)
        for t in range(targets):
            te = rng.normal(0, target_sd)
            for j in range(tracks):
                base = 0.5 + se + te + rng.normal(0, 0.01)
                for m in "ab":
                    v = base + (effect + de if m == "a" else 0.0)
                    rows.append({"scan": f"S{s:03d}", "target": f"S{s:03d}/t{t}", "track": j, "setting": "x",
                                 "method": m, METRIC: v})
    return pd.DataFrame(rows)


def _pooled(b, m="a"):
    return b["pooled"][m][METRIC]


def test_the_point_value_is_the_mean_over_scans_of_their_target_pools():
    cells = scans_population(np.random.default_rng(0), n_scans=3)
    # Unequal scans: drop two targets of the first scan, one track of a target of the second.
    cells = cells[~cells["target"].isin(["S000/t1", "S000/t2"])]
    cells = cells[~((cells["target"] == "S001/t0") & (cells["track"] == 1))]
    b = population_block(cells, ["a", "b"], [METRIC], AB, 300, 0, per_target=False, loto=False, by_scan=True)
    a = cells[cells["method"] == "a"]
    per_target = a.groupby(["scan", "target"])[METRIC].mean()
    expect = per_target.groupby(level="scan").mean().mean()
    assert _pooled(b)["value"] == pytest.approx(expect, abs=1e-12)
    assert _pooled(b)["over"] == ["scans", "targets", "tracks"]
    assert _pooled(b)["n"]["scans"] == 3
    flat = population_block(cells, ["a", "b"], [METRIC], AB, 300, 0, per_target=False, loto=False)
    assert flat["pooled"]["a"][METRIC]["value"] == pytest.approx(per_target.mean(), abs=1e-12)
    assert flat["pooled"]["a"][METRIC]["value"] != pytest.approx(expect, abs=1e-6)   # the weighting differs


def test_scans_that_differ_widen_the_interval_the_flat_bootstrap_understates():
    # Targets of one scan share its effect: resampling targets as if independent understates the
    # spread of the population mean; resampling scans first does not.
    cells = scans_population(np.random.default_rng(1), n_scans=8, targets=5, scan_sd=0.2, target_sd=0.01)
    by_scan = population_block(cells, ["a", "b"], [METRIC], AB, 1000, 0, per_target=False, loto=False, by_scan=True)
    flat = population_block(cells.drop(columns="scan"), ["a", "b"], [METRIC], AB, 1000, 0, per_target=False,
                            loto=False)
    w = lambda e: e["ci_high"] - e["ci_low"]
    assert w(_pooled(by_scan)) > 1.8 * w(flat["pooled"]["a"][METRIC])
    # the target clustering of cells that name their scans counts them too (the design's interval)
    named = population_block(cells, ["a", "b"], [METRIC], AB, 1000, 0, per_target=False, loto=False)
    assert w(named["pooled"]["a"][METRIC]) > 1.8 * w(flat["pooled"]["a"][METRIC])
    # Sampling the population itself: the scan-level interval's width is the right size (the
    # population mean's sd over repeated populations is about scan_sd / sqrt(8) = 0.071).
    assert 0.5 * 2 * 1.96 * 0.2 / math.sqrt(8) < w(_pooled(by_scan)) < 1.5 * 2 * 1.96 * 0.2 / math.sqrt(8)


def test_a_scan_column_puts_the_scans_in_the_target_clusterings_interval():
    # Before, the target clustering ignored the scans the cells name (real.toml: 55 % coverage with
    # scan effects, docs/calibration.md); the design's interval now varies over them too.
    cells = scans_population(np.random.default_rng(2), n_scans=8)
    plain = population_block(cells.drop(columns="scan"), ["a", "b"], [METRIC], AB, 300, 0)
    named = population_block(cells, ["a", "b"], [METRIC], AB, 300, 0)
    p, n = plain["pooled"]["a"][METRIC], named["pooled"]["a"][METRIC]
    assert p["value"] == n["value"] and p["over"] == ["targets", "tracks"]
    assert n["over"] == ["targets", "scans", "tracks"] and n["levels"] == {"targets": 24, "scans": 8}
    assert n["ci_high"] - n["ci_low"] > p["ci_high"] - p["ci_low"]


def test_per_target_values_and_leave_one_out_keep_targets_then_tracks():
    cells = scans_population(np.random.default_rng(3), n_scans=4, effect=0.1, diff_scan_sd=0.02)
    on = population_block(cells, ["a", "b"], [METRIC], AB, 300, 0, by_scan=True)
    off = population_block(cells, ["a", "b"], [METRIC], AB, 300, 0)
    assert on["per_target"] == off["per_target"] and on["paired_per_target"] == off["paired_per_target"]
    rec_on, rec_off = on["records"][0], off["records"][0]
    assert rec_on["loto_min"] == rec_off["loto_min"] and rec_on["over"] == ["scans", "targets", "tracks"]


def test_a_target_split_over_scans_is_one_unit_per_scan():
    cells = scans_population(np.random.default_rng(4), n_scans=2, targets=1, tracks=2)
    cells["target"] = "t"                      # the same object in both scans, tracks 0-1 and 2-3
    cells.loc[cells["scan"] == "S001", "track"] += 2
    h = Hierarchy({"run": cells[cells["method"] == "a"]}, 200, 0, by_scan=True)
    assert h.rs.shape == (2, 1, 2) and h.target_rs.shape == (1, 1, 4)
    assert h.n() == {"targets": 1, "tracks": 4, "scans": 2, "scan_targets": 2}
    bad = cells.copy()
    bad.loc[(bad["scan"] == "S001") & (bad["track"] == 2), "track"] = 0   # one (target, track) in two scans
    with pytest.raises(ValueError, match="more than one scan"):
        Hierarchy({"run": bad}, 200, 0, by_scan=True)


def test_two_scans_withhold_the_median_as_the_mean_one_rule():
    # real.toml's design: 2 scans. The mean's t interval was withheld while the median over targets
    # (log10 MGR percentiles, NLL) still got a bootstrap CI and a verdict; one rule now withholds both.
    mgr = "log10_mgr95_final"
    assert M.pool_of(mgr) == "median"
    cells = scans_population(np.random.default_rng(5), n_scans=2, targets=6, effect=0.3)
    cells[mgr] = cells[METRIC] * 2.0
    b = population_block(cells, ["a", "b"], [METRIC, mgr], AB, 300, 0, primary=[METRIC, mgr])
    for metric in (METRIC, mgr):
        pooled = b["pooled"]["a"][metric]
        assert "2 scans" in pooled["withheld"] and math.isnan(pooled["ci_low"]) and math.isnan(pooled["ci_high"])
    recs = {r["metric"]: r for r in b["records"]}
    assert recs[mgr]["interval"] == "percentile bootstrap"
    for r in recs.values():   # no verdict, not "not distinguishable"; never entered Holm as if tested
        assert r["outcome"] == "withheld" and "2 scans" in r["withheld"]
        assert "outcome_holm" not in r and "p" not in r
    # with 8 scans the same median has its interval and verdict
    many = scans_population(np.random.default_rng(5), n_scans=8, targets=2, effect=0.3)
    many[mgr] = many[METRIC] * 2.0
    r = next(r for r in population_block(many, ["a", "b"], [METRIC, mgr], AB, 300, 0)["records"]
             if r["metric"] == mgr)
    assert "withheld" not in r and r["outcome"] == "worse" and r["lo"] > 0
