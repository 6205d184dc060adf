"""The design's clusters on top of the resampler (evaluate.statistics.cluster): categories over their
targets, and the two-way (crossed) bootstrap of objects x scans; both on populations generated here
where the target-level interval is too narrow."""
import math

import numpy as np
import pandas as pd
import pytest
from scipy.stats import t as student_t

from pipeline.evaluation.statistics import design as D
from pipeline.evaluation.statistics.crossed import weighted_pool
from pipeline.evaluation.statistics.engine import Hierarchy, population_block
from tests.pipeline.evaluation.statistics.test_scan_level import scans_population

AB = [("a", "b")]
METRIC = "correct_final"


def _width(e):
    return e["ci_high"] - e["ci_low"]


def categories_population(rng, n_cat=8, per_cat=6, tracks=2, cat_sd=0.15, target_sd=0.01):
    """Targets '<category>__f<k>' sharing their category's effect (fold-mates, systematic confusions):
    the scan-level generator's groups, named as categories."""
    cells = scans_population(rng, n_scans=n_cat, targets=per_cat, tracks=tracks, scan_sd=cat_sd,
                             target_sd=target_sd, diff_scan_sd=cat_sd)
    cells["target"] = cells["target"].str.replace(r"S(\d+)/t(\d+)", r"cat\1__f\2", regex=True)
    cells["scan"] = "S0"
    return cells


def test_categories_on_top_widen_the_interval_the_target_level_understates():
    cells = categories_population(np.random.default_rng(0))
    flat = population_block(cells, ["a", "b"], [METRIC], AB, 2000, 0, per_target=False, loto=False)
    cat = population_block(cells, ["a", "b"], [METRIC], AB, 2000, 0, per_target=False, loto=False, cluster="category")
    d_flat, d_cat = flat["paired"]["a-b"][METRIC], cat["paired"]["a-b"][METRIC]
    assert d_cat["value"] == pytest.approx(d_flat["value"], abs=1e-12)      # equal categories: same point value
    assert _width(d_cat) > 1.8 * _width(d_flat)
    # the category-level spread: the between-category sd of the difference over sqrt(8 categories)
    per_cat = cells.pivot_table(index=["target", "track"], columns="method", values=METRIC)
    dd = (per_cat["a"] - per_cat["b"]).groupby(lambda i: i[0].split("__f")[0]).mean()
    want = dd.std(ddof=0) / math.sqrt(len(dd))
    assert 0.7 * want < d_cat["se"] < 1.3 * want
    # the half-width's multiplier is the wild bootstrap's quantile of |t| (design.TStat): above the normal's
    assert _width(d_cat) / (2 * d_cat["se"]) > 1.96 and d_cat["interval"] == D.INTERVAL
    rec = cat["records"][0]
    assert rec["cluster"] == "category" and rec["over"] == ["categories", "targets", "tracks"]
    assert rec["n"]["categories"] == 8 and flat["records"][0]["cluster"] == "target"


def test_a_target_outside_any_category_is_named():
    cells = categories_population(np.random.default_rng(1), n_cat=2, per_cat=2)
    cells.loc[cells["target"] == "cat000__f0", "target"] = "loose"
    with pytest.raises(ValueError, match="'loose' has no fold suffix"):
        Hierarchy({"run": cells[cells["method"] == "a"]}, 100, 0, cluster="category")


def crossed_population(rng, n_obj=20, n_scans=8, tracks=2, obj_sd=0.05, scan_sd=0.15):
    """Every object in every scan (a crossed design): an object effect and a scan effect on the
    difference, each shared by every cell of its row or column."""
    oe, se = rng.normal(0, obj_sd, n_obj), rng.normal(0, scan_sd, n_scans)
    rows = []
    for o in range(n_obj):
        for s in range(n_scans):
            for j in range(tracks):
                base = rng.normal(0.5, 0.05)
                for m in "ab":
                    rows.append({"scan": f"S{s}", "target": f"o{o:02d}", "track": s * tracks + j, "setting": "x",
                                 "method": m, METRIC: base + (0.02 + oe[o] + se[s] + rng.normal(0, 0.01)
                                                              if m == "a" else 0.0)})
    return pd.DataFrame(rows), oe, se


def test_the_crossed_bootstrap_counts_the_scans_that_every_object_shares():
    cells, oe, se = crossed_population(np.random.default_rng(2))
    flat = population_block(cells.drop(columns="scan"), ["a", "b"], [METRIC], AB, 2000, 0, per_target=False,
                            loto=False)
    crossed = population_block(cells, ["a", "b"], [METRIC], AB, 2000, 0, per_target=False, loto=False,
                               cluster="crossed")
    d_flat, d_x = flat["paired"]["a-b"][METRIC], crossed["paired"]["a-b"][METRIC]
    assert d_x["value"] == pytest.approx(d_flat["value"], abs=1e-12)        # the point value is the data's own
    # every object sees every scan: the target-level bootstrap cannot see the scan effect at all
    assert _width(d_x) > 2 * _width(d_flat)
    # two-way: sigma_o^2/O + sigma_s^2/S, at t with min(O, S) - 1 = 7 degrees of freedom (design.t_interval)
    want = 2 * student_t.ppf(0.975, 7) * math.sqrt(oe.var() / len(oe) + se.var() / len(se))
    assert 0.7 * want < _width(d_x) < 1.3 * want
    # common random numbers: the paired difference's draws are the difference of the methods' draws
    h = Hierarchy({"run": cells[cells["method"] == "a"]}, 2000, 0, cluster="crossed")
    from pipeline.evaluation.statistics.engine import track_values
    va = h.pad([track_values(cells[cells["method"] == "a"], [METRIC])], METRIC)
    vb = h.pad([track_values(cells[cells["method"] == "b"], [METRIC])], METRIC)
    assert np.allclose(h.rs.draws(va - vb, "mean"), h.rs.draws(va, "mean") - h.rs.draws(vb, "mean"), atol=1e-12)
    rec = crossed["records"][0]
    assert rec["cluster"] == "crossed" and rec["over"] == ["targets", "scans"]
    assert rec["n"]["scans"] == 8 and rec["n"]["targets"] == 20


def test_unbalanced_crossed_cells_keep_the_point_value_and_a_missing_scan_drops_its_tracks():
    cells, _, _ = crossed_population(np.random.default_rng(3), n_obj=5, n_scans=4)
    cells = cells[~((cells["target"] == "o00") & (cells["scan"] != "S0"))]     # o00 seen in one scan only
    x = population_block(cells, ["a", "b"], [METRIC], AB, 500, 0, per_target=False, loto=False, cluster="crossed")
    t = population_block(cells, ["a", "b"], [METRIC], AB, 500, 0, per_target=False, loto=False)
    assert x["pooled"]["a"][METRIC]["value"] == pytest.approx(t["pooled"]["a"][METRIC]["value"], abs=1e-12)
    h = Hierarchy({"run": cells[cells["method"] == "a"]}, 500, 0, cluster="crossed")
    # draws where scan S0 is not drawn: o00 has no track, so it weighs nothing there
    w, wt = h.rs._weights(h.rs.m_obj.astype(float), h.rs.m_scan.astype(float))
    no_s0 = h.rs.m_scan[:, h.groups.index("S0")] == 0
    assert no_s0.any() and (wt[no_s0, h.targets.index("o00")] == 0).all()


@pytest.mark.parametrize("seed", range(5))
def test_the_weighted_median_is_the_median_of_the_repeated_values(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(50, 7))
    w = rng.integers(0, 4, size=(50, 7))
    w[:, 0] = np.maximum(w[:, 0], 1)
    got = weighted_pool(x, w, "median")
    want = [np.median(np.repeat(x[i], w[i])) for i in range(50)]
    assert np.allclose(got, want)
    assert np.allclose(weighted_pool(x, w, "mean"), [np.mean(np.repeat(x[i], w[i])) for i in range(50)])
    x[0, 0] = np.nan
    assert np.isnan(weighted_pool(x, w, "median")[0])


def test_crossed_draws_share_their_weights_across_statistics():
    from pipeline.evaluation.statistics.crossed import CrossedResampler

    rng = np.random.default_rng(5)
    scan_of = rng.integers(0, 4, (6, 3))
    scan_of[2, 1:] = -1
    rs = CrossedResampler(scan_of, 300, [1])
    for pool in ("mean", "median", "mean"):
        v = rng.random((1, 6, 3))
        v[0, 4, 0] = np.nan            # a real NaN: the draws holding that track give NaN
        v[0, 2, 2] = np.nan            # a padded slot's NaN: never read
        got = rs.draws(v, pool)
        fresh = rs._stat(v, rs._prepared(rs.m_obj.astype(float), rs.m_scan.astype(float)), pool)
        assert np.array_equal(got, fresh, equal_nan=True)
        w, _ = rs._weights(rs.m_obj.astype(float), rs.m_scan.astype(float))
        assert np.array_equal(np.isnan(got), w[:, 4, 0] * rs.m_obj[:, 4] > 0)
