"""Leave-one-target-out from the draws already made (jackknife-after-bootstrap) against the previous
route that re-resampled each subset (tests/support/loto_reference.py), on a population generated
here with a fixed seed: the values are the same statistic; each interval end agrees within the
Monte Carlo error docs/design.md §8 states (in probability level sqrt(p (1 - p) / draws) per end;
about 2.7 sigma / sqrt(draws) for a near-normal statistic)."""
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.statistics.engine import Hierarchy, population_block, track_values
from pipeline.evaluation.statistics.hierarchy import loto_estimates
from pipeline.evaluation.statistics.pooled_calibration import hierarchy_of, pooled_ece, track_sums
from tests.support import loto_reference as REF

METRIC = "correct_final"
MC = 2.7          # a 2.5 % / 97.5 % percentile's Monte Carlo SE is ~2.7 sigma / sqrt(draws) (normal statistic)


def population(seed=0, n_targets=14, effect=0.03):
    """Cells of two methods on targets with 2-7 tracks; 'a' - 'b' varies by target around ``effect``."""
    rng = np.random.default_rng(seed)
    rows = []
    for t in range(n_targets):
        te, de = rng.normal(0.5, 0.15), rng.normal(effect, 0.05)
        for j in range(int(rng.integers(2, 8))):
            base = te + rng.normal(0, 0.05)
            for m in "ab":
                rows.append({"target": f"t{t:02d}", "track": j, "setting": "x", "method": m,
                             METRIC: base + (de + rng.normal(0, 0.03) if m == "a" else 0.0)})
    return pd.DataFrame(rows)


def _diff_values(cells, h):
    a = cells[cells["method"] == "a"].set_index(["target", "track", "setting"])[METRIC]
    b = cells[cells["method"] == "b"].set_index(["target", "track", "setting"])[METRIC]
    d = (a - b).reset_index().assign(method="diff")
    return h.pad([track_values(d, [METRIC])], METRIC)


@pytest.mark.parametrize("pool", ["mean", "median"])
def test_left_out_values_equal_and_interval_ends_agree_within_the_stated_monte_carlo_error(pool):
    cells = population()
    B = 2000
    h = Hierarchy({"run": cells[cells["method"] == "a"]}, B, 0)
    v = _diff_values(cells, h)
    rs = h.target_rs
    new = loto_estimates(h, rs.leave_one_out_points(v, pool), rs.draws(v, pool, slots=rs.shape[1] - 1))
    old = REF.estimates(h, v, pool)
    left_out = rs.left_out(rs.shape[1] - 1)
    T = len(h.targets)
    assert left_out.sum(axis=0).min() > 0.3 * B                    # ~ B (1 - 1/T)^(T-1) draws per target
    assert abs(left_out.mean() - (1 - 1 / T) ** (T - 1)) < 0.02
    draws_loo = rs.draws(v, pool, slots=T - 1)
    for ti, (n, o) in enumerate(zip(new, old)):
        assert n["value"] == pytest.approx(o["value"], abs=1e-12)
        d, k = draws_loo[left_out[:, ti]], left_out[:, ti].sum()
        for p, end in ((0.025, "ci_low"), (0.975, "ci_high")):
            # distribution-free: the old end's level among the new draws is p within 4 MC errors
            tol_p = 4 * math.sqrt(p * (1 - p) * (1 / k + 1 / B))
            assert np.mean(d < o[end]) - tol_p <= p <= np.mean(d <= o[end]) + tol_p, (ti, end, n, o)
            if pool == "mean":   # a near-normal statistic: the ends within 4 x 2.7 sigma / sqrt(draws)
                tol = 4 * MC * float(np.std(d)) * math.sqrt(1 / k + 1 / B)
                assert abs(n[end] - o[end]) < tol, (ti, end, n, o, tol)


def test_the_engine_records_read_the_new_route_and_its_flips_match_the_old_away_from_zero():
    cells = population(seed=3, effect=0.02)
    B = 2000
    b = population_block(cells, ["a", "b"], [METRIC], [("a", "b")], B, 0, primary=(METRIC,))
    rec = b["records"][0]
    h = Hierarchy({"run": cells[cells["method"] == "a"]}, B, 0)
    v = _diff_values(cells, h)
    ref = REF.leave_one_out(h, v, "mean", True)
    assert rec["loto_min"] == pytest.approx(ref["loto_min"], abs=1e-12)
    assert rec["loto_max"] == pytest.approx(ref["loto_max"], abs=1e-12)
    # a flip can differ only where an end of that target's interval lies within the MC error of 0
    old = {t: e for t, e in zip(h.targets, REF.estimates(h, v, "mean"))}
    sigma = float(np.std(h.target_rs.draws(v, "mean")))
    near = {t for t, e in old.items() if min(abs(e["ci_low"]), abs(e["ci_high"])) < 4 * MC * sigma / math.sqrt(0.3 * B)}
    assert set(rec["loto_flips"]) ^ set(ref["loto_flips"]) <= near


def test_the_pooled_ece_left_out_values_are_the_ece_of_the_other_targets():
    from types import SimpleNamespace

    rng = np.random.default_rng(2)
    cells, results = [], []
    for t in range(5):
        for j in range(int(rng.integers(1, 4))):
            lp = {m: np.log(rng.dirichlet(np.ones(3) * (0.3 if m == "a" else 3.0), size=(4, 3))) for m in "ab"}
            cells.append(SimpleNamespace(variant="default", target=f"t{t}", track=j, truth=t % 3))
            results.append({"posts": {("randomized", "s"): lp}})
    sums = track_sums(cells, results, "default", 10)
    d = pooled_ece(hierarchy_of(sums, 400, 0), sums, ["a", "b"], [("a", "b")])["paired"]["a-b"]["ece_final"]
    vals = []
    for t in range(5):
        sub = {k: s for k, s in sums.items() if k[1] != f"t{t}"}
        p = pooled_ece(hierarchy_of(sub, 100, 0), sub, ["a", "b"], [], loto=False)["pooled"]
        vals.append(p["a"]["ece_final"]["value"] - p["b"]["ece_final"]["value"])
    assert d["loto_min"] == pytest.approx(min(vals), abs=1e-12) and d["loto_max"] == pytest.approx(max(vals), abs=1e-12)
