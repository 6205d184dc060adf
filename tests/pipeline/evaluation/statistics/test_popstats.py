"""Population statistics: bootstrap coverage, paired differences, verdicts computed from CIs."""
import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.popstats import hierarchical, paired_differences, population_block, verdict

MET = list(METRICS)


def population(rng, n_targets=8, n_tracks=6, settings=2, effect=0.0, methods=("a", "b")):
    """Cells with a target effect, a track effect and noise; method 'a' adds ``effect`` to the
    correct ratios (higher is better) and subtracts it from the log10 MGRs (lower is better)."""
    rows = []
    for t in range(n_targets):
        te = rng.normal(0, 0.1)
        for j in range(n_tracks):
            je = rng.normal(0, 0.05)
            for s in range(settings):
                base = 0.5 + te + je + rng.normal(0, 0.02)
                for m in methods:
                    shift = effect if m == "a" else 0.0
                    row = {"target": f"t{t}", "track": j, "setting": f"s{s}", "method": m}
                    for k, higher in ((k, m.higher_is_better) for k, m in METRICS.items()):
                        row[k] = base + (shift if higher else -shift)
                    rows.append(row)
    return pd.DataFrame(rows)


def test_bootstrap_ci_covers_the_true_mean_at_about_the_nominal_rate():
    # Two-level data with a known population mean: targets ~ N(mu, 1), tracks ~ N(target, 0.5).
    rng = np.random.default_rng(0)
    mu, hits, reps = 2.0, 0, 200
    for r in range(reps):
        groups = [rng.normal(rng.normal(mu, 1.0), 0.5, size=6) for _ in range(25)]
        est = hierarchical(groups, 400, [r])
        hits += est["ci_low"] <= mu <= est["ci_high"]
    rate = hits / reps
    assert 0.88 <= rate <= 0.99, rate     # nominal 0.95; percentile intervals run a little narrow


def test_interval_shrinks_with_more_targets_and_holds_the_value():
    rng = np.random.default_rng(1)
    small = hierarchical([rng.normal(0, 1, 5) for _ in range(5)], 500, 0)
    large = hierarchical([rng.normal(0, 1, 5) for _ in range(80)], 500, 0)
    assert large["ci_high"] - large["ci_low"] < small["ci_high"] - small["ci_low"]
    for e in (small, large):
        assert e["ci_low"] <= e["value"] <= e["ci_high"]


def test_difference_of_a_method_with_itself_is_exactly_zero():
    cells = population(np.random.default_rng(2))
    same = cells[cells["method"] == "a"].copy()
    twin = same.assign(method="b")
    pooled, per_target = paired_differences(pd.concat([same, twin]), "a", "b", MET, 300, 0)
    for k in MET:
        assert pooled[k]["value"] == 0.0 and pooled[k]["ci_low"] == 0.0 and pooled[k]["ci_high"] == 0.0
        assert pooled[k]["wins"] == 0.0 and pooled[k]["losses"] == 0.0
        assert all(v[k]["value"] == 0.0 and v[k]["ci_low"] == 0.0 == v[k]["ci_high"] for v in per_target.values())


def test_verdict_follows_the_sign_and_flips_when_the_inputs_flip():
    rng = np.random.default_rng(3)
    better = population(rng, effect=0.2)
    block = population_block(better, ["a", "b"], MET, [("a", "b")], 500, 0, "8 targets x 6 tracks")
    rows = block["verdict_table"]
    assert set(block["per_target"]) == {f"t{t}" for t in range(8)}          # per-target values are kept
    for per in block["per_target"].values():
        assert per["a"]["correct_final"]["ci_low"] <= per["a"]["correct_final"]["value"] <= per["a"]["correct_final"]["ci_high"]
    assert {r["outcome"] for r in rows} == {"better"}
    assert all(" is better than " in s and "95 % CI" in s and "8 targets x 6 tracks" in s for s in block["verdict"])
    flipped = better.assign(method=better["method"].map({"a": "b", "b": "a"}))
    block2 = population_block(flipped, ["a", "b"], MET, [("a", "b")], 500, 0, "8 targets x 6 tracks")
    assert {r["outcome"] for r in block2["verdict_table"]} == {"worse"}
    # No effect: the CI straddles zero.
    none = population(np.random.default_rng(4), effect=0.0)
    none.loc[none["method"] == "a", MET] += np.random.default_rng(5).normal(0, 0.01, (len(none) // 2, len(MET)))
    block3 = population_block(none, ["a", "b"], MET, [("a", "b")], 500, 0, "x")
    assert {r["outcome"] for r in block3["verdict_table"]} == {"not distinguishable"}


def test_saturated_cells_are_counted_in_the_sentence():
    cells = population(np.random.default_rng(6), effect=0.0)
    cells["correct_final"] = 1.0
    paired, _ = paired_differences(cells, "a", "b", ["correct_final"], 200, 0)
    sentences, rows = verdict(cells, {"a-b": paired}, "scope")
    assert rows[0]["ceiling_cells"] == len(cells) // 2 and rows[0]["outcome"] == "not distinguishable"
    assert f"{len(cells) // 2} of {len(cells) // 2} cells had both methods at the best possible value" in sentences[0]


def test_mismatched_cells_are_an_error():
    cells = population(np.random.default_rng(7))
    with pytest.raises(ValueError, match="same cells"):
        paired_differences(cells.iloc[1:], "a", "b", MET, 100, 0)


def test_wilson_interval_matches_the_closed_form_and_stays_in_0_1():
    from pipeline.evaluation.statistics.popstats import wilson_interval

    lo, hi = wilson_interval(8, 10)          # textbook value: [0.490, 0.943]
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    a, b = wilson_interval(1107, 1200), wilson_interval(110, 120)
    assert a[1] - a[0] < b[1] - b[0]          # more images, a narrower interval
