"""The scan level of the one resampler (scans -> targets -> tracks) and the power block (the
population a primary comparison's interval would need)."""
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.engine import Hierarchy, population_block
from pipeline.evaluation.statistics.power import needed_units, power_block

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


def test_needed_units_scale_as_the_square_of_the_width_ratio():
    assert needed_units(0.10, 10) == 40
    assert needed_units(0.05, 10) == 10 and needed_units(0.01, 10) == 10
    assert needed_units(math.inf, 10) is None and needed_units(math.nan, 10) is None


def test_the_projected_population_reaches_the_goal_half_width():
    # Observe a small population, project the scans that would make the difference's half-width
    # 0.05, draw a population of that size from the same process: its half-width lands near 0.05.
    gen = dict(targets=3, tracks=2, scan_sd=0.1, diff_scan_sd=0.15, effect=0.05)
    small = scans_population(np.random.default_rng(5), n_scans=8, **gen)
    b = population_block(small, ["a", "b"], [METRIC], AB, 1000, 0, primary=(METRIC,), per_target=False, loto=False,
                         by_scan=True)
    p = power_block(b["records"], seconds=10.0, available={"scans": 15})
    (e,) = p["comparisons"]
    assert e["unit"] == "scans" and e["n_units"] == 8 and not e["reached"]
    assert e["needed_units"] == needed_units(e["half_width"], 8)
    assert e["needed_targets"] == math.ceil(e["scale"] * 24) and e["cost_s"] == pytest.approx(10.0 * e["scale"])
    assert e["beyond"].startswith(f"{e['needed_units']} scans needed")
    big = scans_population(np.random.default_rng(6), n_scans=e["needed_units"], **gen)
    bb = population_block(big, ["a", "b"], [METRIC], AB, 1000, 0, primary=(METRIC,), per_target=False, loto=False,
                          by_scan=True)
    w = (bb["records"][0]["hi"] - bb["records"][0]["lo"]) / 2
    assert 0.03 < w < 0.075
    assert power_block(bb["records"])["comparisons"][0]["needed_units"] <= 2 * e["needed_units"]


def test_only_primary_records_get_a_power_entry_and_unbounded_ends_get_none():
    recs = [{"comparison": "a-b", "metric": "x", "lo": -0.2, "hi": 0.1, "primary": True, "over": ["targets", "tracks"],
             "n": {"targets": 12, "tracks": 35}},
            {"comparison": "a-b", "metric": "y", "lo": None, "hi": 0.1, "primary": True, "over": ["targets", "tracks"],
             "n": {"targets": 12, "tracks": 35}},
            {"comparison": "a-b", "metric": "z", "lo": -0.2, "hi": 0.1, "primary": False, "over": ["targets"],
             "n": {"targets": 12}}]
    p = power_block(recs, seconds=None)["comparisons"]
    assert [e["metric"] for e in p] == ["x", "y"]
    assert p[0]["half_width"] == pytest.approx(0.15) and p[0]["needed_units"] == 108 and p[0]["cost_s"] is None
    assert p[1]["needed_units"] is None and p[1]["half_width"] == math.inf


def test_too_few_units_carry_a_caution():
    rec = {"comparison": "a-b", "metric": "x", "lo": -0.2, "hi": 0.1, "primary": True,
           "over": ["scans", "targets", "tracks"], "n": {"scans": 2, "targets": 6, "tracks": 8}}
    (e,) = power_block([rec])["comparisons"]
    assert e["unit"] == "scans" and "caution" in e
    (e,) = power_block([dict(rec, n={"scans": 15, "targets": 60, "tracks": 200})])["comparisons"]
    assert "caution" not in e
