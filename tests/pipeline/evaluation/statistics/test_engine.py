"""The statistics engine: one resampler shared by every metric and method, one interval and
infinity rule, one outcome rule, records that agree with their intervals."""
import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.engine import (
    over_members,
    population_block,
    seed_block,
)
from pipeline.evaluation.statistics.records import consistent, outcome
from pipeline.evaluation.statistics.resampler import (
    Resampler,
    draws,
    interval,
    wilson_interval,
)
from pipeline.infra.cache import write_json

AB = [("a", "b")]


def population(rng, n_targets=8, tracks=(6, 3, 5, 1, 6, 4, 6, 2), settings=2, effect=0.0):
    """Cells with a target effect, a track effect and noise; method 'a' is ``effect`` better on
    every metric (higher-is-better ones up, the others down)."""
    rows = []
    for t in range(n_targets):
        te = rng.normal(0, 0.1)
        for j in range(tracks[t]):
            je = rng.normal(0, 0.05)
            for s in range(settings):
                base = 0.5 + te + je + rng.normal(0, 0.02)
                for m in "ab":
                    shift = effect if m == "a" else 0.0
                    row = {"target": f"t{t}", "track": j, "setting": f"s{s}", "method": m}
                    for k, mm in M.METRICS.items():
                        row[k] = base + (shift if mm.higher_is_better else -shift) + rng.normal(0, 0.01)
                    rows.append(row)
    return pd.DataFrame(rows)


def _record(block, metric):
    return next(r for r in block["records"] if r["metric"] == metric)


def test_equivalent_metrics_give_identical_verdicts(request):
    # A metric that is 4 x another (Brier = 4 x MSDE with 4 candidates) is the same quantity: with
    # shared draws its interval is exactly 4 x the other's and its outcome the same, for the mean
    # and for the median pooling.
    for pool, base in (("mean", "msde_final"), ("median", "nll_final")):
        scaled = dataclasses.replace(M.METRICS[base], label="4 x", pool=pool)
        M.unregister_metric("scaled")
        M.register_metric("scaled", scaled)
        request.addfinalizer(lambda: M.unregister_metric("scaled"))
        cells = population(np.random.default_rng(3), effect=0.004)
        cells["scaled"] = 4 * cells[base]
        b = population_block(cells, ["a", "b"], [base, "scaled"], AB, 600, 0)
        r, s = _record(b, base), _record(b, "scaled")
        assert r["pooling"] == s["pooling"] == pool
        assert s["outcome"] == r["outcome"]
        np.testing.assert_allclose([s["value"], s["lo"], s["hi"]], [4 * r["value"], 4 * r["lo"], 4 * r["hi"]],
                                   rtol=1e-12, atol=1e-15)
        pa, ps = b["pooled"]["a"][base], b["pooled"]["a"]["scaled"]
        np.testing.assert_allclose([ps["ci_low"], ps["ci_high"]], [4 * pa["ci_low"], 4 * pa["ci_high"]], rtol=1e-12)


def test_one_draw_set_serves_every_metric_and_method():
    rs = draws([[3, 2, 4]], 500, 7)
    assert draws([[3, 2, 4]], 500, 7) is rs                       # made once, shared
    rng = np.random.default_rng(0)
    va, vb = rng.normal(size=(1, 3, 4)), rng.normal(size=(1, 3, 4))
    # for the mean the paired draws are exactly the difference of the two methods' draws
    np.testing.assert_allclose(rs.draws(va - vb, "mean"), rs.draws(va, "mean") - rs.draws(vb, "mean"), atol=1e-12)
    # leaf weights give the same mean statistic as the slot means (the ECE uses the weights)
    w = rs.leaf_weights()
    np.testing.assert_allclose(np.einsum("bstw,stw->b", w, va), rs.draws(va, "mean"), atol=1e-12)
    np.testing.assert_allclose(w.sum(axis=(1, 2, 3)), 1.0)


def _textbook(groups, n_boot, rng):
    """The two-level bootstrap written out: targets with replacement, then each drawn target's
    tracks with replacement; the mean over target slots of the slot means."""
    out = []
    for _ in range(n_boot):
        picks = rng.integers(0, len(groups), len(groups))
        out.append(np.mean([rng.choice(groups[p], len(groups[p])).mean() for p in picks]))
    return np.percentile(out, [2.5, 97.5])


def test_the_shared_resampler_reproduces_the_textbook_interval():
    # Where the statistic did not change (a mean over targets of target means) the new resampler
    # gives the interval of the previous two-level bootstrap up to Monte Carlo noise: each end
    # within 8 % of the interval's width (about 5 standard errors at 4000 draws).
    rng = np.random.default_rng(11)
    groups = [rng.normal(rng.normal(0.5, 0.2), 0.1, size=n) for n in (6, 3, 5, 1, 6, 4, 6, 2, 5, 3)]
    width = max(len(g) for g in groups)
    v = np.zeros((1, len(groups), width))
    for t, g in enumerate(groups):
        v[0, t, : len(g)] = g
    est = Resampler([[len(g) for g in groups]], 4000, 1).estimate(v, "mean")
    lo, hi = _textbook(groups, 4000, np.random.default_rng(2))
    assert est["value"] == pytest.approx(np.mean([g.mean() for g in groups]))
    tol = 0.08 * (hi - lo)
    assert abs(est["ci_low"] - lo) < tol and abs(est["ci_high"] - hi) < tol


def test_bootstrap_ci_covers_the_true_mean_at_about_the_nominal_rate():
    rng = np.random.default_rng(0)
    mu, hits, reps = 2.0, 0, 150
    for r in range(reps):
        groups = [rng.normal(rng.normal(mu, 1.0), 0.5, size=6) for _ in range(25)]
        est = Resampler([[6] * 25], 400, [r]).estimate(np.array([groups]), "mean")
        hits += est["ci_low"] <= mu <= est["ci_high"]
    assert 0.87 <= hits / reps <= 0.995, hits / reps


def test_the_number_shown_its_ci_and_its_verdict_are_one_statistic():
    cells = population(np.random.default_rng(4), effect=0.03)
    b = population_block(cells, ["a", "b"], list(M.METRICS), AB, 400, 0, primary=("correct_final",))
    for r in b["records"]:
        p = b["paired"]["a-b"][r["metric"]]
        assert (r["value"], r["lo"], r["hi"]) == (p["value"], p["ci_low"], p["ci_high"])
        assert r["pooling"] == p["pooling"] == M.pool_of(r["metric"]) and consistent(r)
        assert r["primary"] == (r["metric"] == "correct_final")
        assert r["over"] == ["targets", "tracks"] and r["n"]["targets"] == 8 and r["n"]["tracks"] == 33
    # an unbounded metric pools by the median over targets of the target means, shown and judged alike
    tv = cells[cells["method"] == "a"].groupby(["target", "track"])["nll_final"].mean().groupby("target").mean()
    assert b["pooled"]["a"]["nll_final"]["value"] == pytest.approx(float(np.median(tv)))
    assert _record(b, "correct_final")["outcome"] == "better"


def test_difference_of_a_method_with_itself_is_exactly_zero_and_not_distinguishable():
    cells = population(np.random.default_rng(2))
    a = cells[cells["method"] == "a"]
    b = population_block(pd.concat([a, a.assign(method="b")]), ["a", "b"], list(M.METRICS), AB, 300, 0)
    for r in b["records"]:
        assert r["value"] == 0.0 and r["lo"] == 0.0 and r["hi"] == 0.0 and r["outcome"] == "not distinguishable"
        assert r["wins"] == 0.0 and r["losses"] == 0.0


def test_outcome_rule_and_record_consistency():
    assert outcome(0.1, 0.3, True) == "better" and outcome(0.1, 0.3, False) == "worse"
    assert outcome(-0.3, -0.1, True) == "worse" and outcome(-0.1, 0.2, True) == "not distinguishable"
    assert outcome(float("nan"), 0.2, True) == "not distinguishable"
    assert outcome(0.1, None, True) == "better"            # null = +inf: unbounded above, still above 0
    assert outcome(None, None, True) == "not distinguishable"
    cells = population(np.random.default_rng(5), effect=0.05)
    rec = _record(population_block(cells, ["a", "b"], ["correct_final"], AB, 300, 0), "correct_final")
    assert rec["outcome"] == "better" and consistent(rec)
    assert not consistent({**rec, "outcome": "not distinguishable"})      # a label against its interval
    assert not consistent({**rec, "value": rec["hi"] + 1.0})             # a value outside its interval
    assert not consistent({**rec, "better": "lower"})                     # the direction flips the label


def test_infinities_are_kept_and_an_infinite_end_is_unbounded(tmp_path):
    cells = population(np.random.default_rng(6), effect=0.05)
    bad = (cells["target"] == "t0") & (cells["track"] == 0) & (cells["method"] == "b")
    cells.loc[bad, ["msde_final", "nll_final"]] = np.inf          # b infinitely bad on one track
    b = population_block(cells, ["a", "b"], ["msde_final", "nll_final"], AB, 300, 0)
    mean = b["pooled"]["b"]["msde_final"]
    assert mean["value"] == np.inf and mean["ci_high"] == np.inf
    med = b["pooled"]["b"]["nll_final"]
    assert np.isfinite(med["value"]) and np.isfinite(med["ci_low"])  # the median is not moved by one target
    r = _record(b, "msde_final")                                     # a - b: -inf on that target
    assert r["unbounded"] and r["lo"] == -np.inf and r["outcome"] == "better" and consistent(r)
    write_json(tmp_path / "s.json", {"records": b["records"]})
    back = json.loads((tmp_path / "s.json").read_text())["records"]
    assert all(consistent(x) for x in back)
    assert next(x for x in back if x["metric"] == "msde_final")["lo"] is None
    lo, hi = interval(np.array([[1.0, np.nan, 2.0]]))
    assert np.isnan(lo[0]) and np.isnan(hi[0])                  # an undefined draw: no interval


def test_seed_level_widens_the_ci_and_one_seed_equals_the_run():
    rng = np.random.default_rng(1)

    def cells(level, n_targets=8, n_tracks=3):
        out = []
        for t in range(n_targets):
            for k in range(n_tracks):
                for s in ("a", "b"):
                    wu = level + rng.normal(0, 0.05)
                    out.append({"target": f"t{t}", "track": k, "setting": s,
                                "values": {"with_uncertainty": {"correct_final": wu, "nll_final": 10 * wu},
                                           "model_based": {"correct_final": wu - 0.1, "nll_final": 10 * wu + 1}}})
        return out

    meth, comps = ["with_uncertainty", "model_based"], [("with_uncertainty", "model_based")]
    levels = np.linspace(0.2, 0.8, 8)
    agree = {str(i): cells(0.5) for i in range(8)}
    differ = {str(i): cells(lv) for i, lv in enumerate(levels)}
    a = seed_block(agree, meth, ["correct_final"], comps, 500)["pooled"]["with_uncertainty"]["correct_final"]
    d = seed_block(differ, meth, ["correct_final"], comps, 500)["pooled"]["with_uncertainty"]["correct_final"]
    assert (d["ci_high"] - d["ci_low"]) > 5 * (a["ci_high"] - a["ci_low"]) and d["over"][0] == "seeds"
    out = seed_block(differ, meth, ["correct_final", "nll_final"], comps, 400, primary=("correct_final",))
    recs = {r["metric"]: r for r in out["records"]}
    assert recs["correct_final"]["value"] == pytest.approx(0.1) and recs["correct_final"]["outcome"] == "better"
    assert recs["nll_final"]["value"] == pytest.approx(-1.0) and recs["nll_final"]["n"]["seeds"] == 8
    # the study / compare pool of one run is the run's own statistic (same draws, same values)
    from pipeline.evaluation.statistics.engine import summary_cells
    one = seed_block({"0": differ["0"]}, meth, ["correct_final", "nll_final"], comps, 400)
    run = population_block(summary_cells(differ["0"]), meth, ["correct_final", "nll_final"], comps, 400, 0)
    for m in meth:
        for k in ("correct_final", "nll_final"):
            x, y = one["pooled"][m][k], run["pooled"][m][k]
            assert np.array_equal([x["value"], x["ci_low"], x["ci_high"]], [y["value"], y["ci_low"], y["ci_high"]],
                                  equal_nan=True)
            assert np.isfinite([x["ci_low"], x["ci_high"]]).all()


def test_a_seed_pool_under_eight_seeds_or_over_runs_with_too_few_scans_is_withheld():
    """The pool's draws resample the seeds on top: with fewer than 8 the percentile interval is not
    calibrated, as for any level; the runs' own scans (which the cells no longer name) count too."""
    from pipeline.evaluation.statistics.engine import seed_pool

    rng = np.random.default_rng(2)

    def pop(level, scans=None):
        cells = [{"target": f"t{t}", "track": k, "setting": "a",
                  "values": {"with_uncertainty": {"correct_final": level + rng.normal(0, 0.05)},
                             "model_based": {"correct_final": level - 0.2 + rng.normal(0, 0.05)}}}
                 for t in range(8) for k in range(3)]
        n = {"targets": 8, "tracks": 24, **({"scans": scans} if scans else {})}
        return {"cells": cells, "bootstrap": 400, "records": [{"n": n}]}

    few = seed_pool({str(i): pop(0.5) for i in range(3)})
    r = next(x for x in few["records"] if x["metric"] == "correct_final")
    assert r["outcome"] == "withheld" and r["withheld"].startswith("3 seeds: ") and np.isnan(r["lo"])
    assert "family" not in r and np.isnan(few["pooled"]["with_uncertainty"]["correct_final"]["ci_low"])
    eight = seed_pool({str(i): pop(0.5) for i in range(8)})
    r = next(x for x in eight["records"] if x["metric"] == "correct_final")
    assert r["outcome"] == "better" and not r.get("withheld") and r["lo"] > 0.1
    scans = seed_pool({str(i): pop(0.5, scans=2) for i in range(8)})
    r = next(x for x in scans["records"] if x["metric"] == "correct_final")
    assert r["outcome"] == "withheld" and r["withheld"].startswith("2 scans: ")
    assert seed_pool({str(i): pop(0.5, scans=8) for i in range(8)})["records"][0]["outcome"] != "withheld"


def test_over_members_and_wilson():
    e = over_members(np.array([1.0, 2.0, 3.0, 4.0]), 500, 0)
    assert e["value"] == 2.5 and 1.0 <= e["ci_low"] < 2.5 < e["ci_high"] <= 4.0
    assert np.isnan(over_members(np.array([1.0]), 500, 0)["ci_low"])   # one member: no interval
    lo, hi = wilson_interval(8, 10)          # textbook value: [0.490, 0.943]
    assert lo == pytest.approx(0.490, abs=1e-3) and hi == pytest.approx(0.943, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0


def test_saturation_counts_cells_where_both_methods_sit_at_an_extreme_in_any_row_order():
    # 'b' lists its cells in another order than 'a': the counts pair cell with cell, with the pair
    # aligned once for every metric or per call.
    from pipeline.evaluation.statistics.engine import aligned_cells, saturation

    metric = next(k for k, m in M.METRICS.items() if m.best is not None and m.worst is not None)
    best, worst = M.METRICS[metric].best, M.METRICS[metric].worst
    keys = [(f"t{t}", j, "s0") for t in range(3) for j in range(4)]
    a = [best, best, worst, worst, best, 0.5, worst, 0.5, best, worst, best, worst]
    b = [best, worst, worst, best, best, best, worst, 0.5, 0.5, worst, best, best]
    rows = [dict(zip(["target", "track", "setting"], k), method=m, **{metric: v})
            for m, vals in (("a", a), ("b", b)) for k, v in zip(keys, vals)]
    cells = pd.DataFrame(rows)
    cells = pd.concat([cells[cells["method"] == "a"], cells[cells["method"] == "b"].iloc[::-1]])
    want = (sum(x == y == best for x, y in zip(a, b)), sum(x == y == worst for x, y in zip(a, b)))
    assert want == (3, 3)
    assert saturation(cells, "a", "b", metric) == want
    assert saturation(cells, "a", "b", metric, aligned_cells(cells, "a", "b")) == want
