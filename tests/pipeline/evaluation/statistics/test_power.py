"""Power from variance components (``pipeline.evaluation.statistics.power``): the moment estimators
recover planted object, scan, interaction and track variances, and the needs they imply reach 80 %."""
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.statistics.power import (components, needed_variance, power_at, power_block, variance)


def crossed(rng, I, J, n, sa, sb, sab, se, effect=0.0):
    """Paired differences of I objects x J scans (every object in every scan), n tracks per cell."""
    a, b = rng.normal(0, sa, I), rng.normal(0, sb, J)
    ab = rng.normal(0, sab, (I, J))
    d = effect + a[:, None, None] + b[None, :, None] + ab[:, :, None] + rng.normal(0, se, (I, J, n))
    i, j, k = np.meshgrid(np.arange(I), np.arange(J), np.arange(n), indexing="ij")
    return pd.DataFrame({"target": [f"o{x}" for x in i.ravel()], "scan": [f"s{x}" for x in j.ravel()],
                         "track": k.ravel(), "d": d.ravel()})


def test_the_moment_estimators_recover_planted_components():
    I, J, n = 300, 150, 3
    c = components(crossed(np.random.default_rng(0), I, J, n, 0.10, 0.08, 0.05, 0.2))
    # each estimate within 4 of its standard errors (chi-square: var * sqrt(2 / dof))
    assert c["object"] == pytest.approx(0.01, abs=4 * 0.01 * math.sqrt(2 / (I - 1)) + 1e-4)
    assert c["scan"] == pytest.approx(0.0064, abs=4 * 0.0064 * math.sqrt(2 / (J - 1)) + 1e-4)
    assert c["track"] == pytest.approx(0.04, abs=4 * 0.04 * math.sqrt(2 / (I * J * (n - 1))))
    assert c["interaction"] == pytest.approx(0.0025, abs=4 * math.sqrt(2 / (I * J)) * (0.0025 + 0.04 / n))
    assert (c["n_objects"], c["n_scans"], c["n_cells"], c["tracks_per_cell"]) == (I, J, I * J, n)


def test_one_scan_leaves_the_scan_term_unestimated_and_says_so():
    c = components(crossed(np.random.default_rng(1), 40, 1, 4, 0.1, 0.0, 0.0, 0.2))
    assert c["scan"] == 0.0 and any("scan term is not estimable" in x for x in c["notes"])
    assert c["object"] == pytest.approx(0.01, abs=4 * 0.01 * math.sqrt(2 / 39) + 4 * 0.04 / 4 * math.sqrt(2 / 39))


def test_power_at_the_needed_standard_error_is_eighty_percent():
    assert power_at(math.sqrt(needed_variance(0.05)), 0.05) == pytest.approx(0.80, abs=1e-3)
    assert power_at(1e9, 0.05) == pytest.approx(0.05, abs=1e-6)       # no signal: the test's size


def _primary():
    return {"comparison": "with_uncertainty-model_based", "metric": "confident_error_final", "setting": "all"}


def test_track_noise_dominant_is_reachable_by_more_tracks_per_target():
    d = crossed(np.random.default_rng(3), 100, 6, 2, 0.01, 0.005, 0.0, 1.2)
    p = power_block(d, _primary(), available={"objects": 100, "scans": 6}, tracks_per_target=8)
    assert p["reading"] == "reachable by the config" and p["power_now"] < 0.8
    c, n = p["components"], p["needed"]["tracks_per_cell"]
    assert variance(c, 100, 6, 600, n) <= needed_variance(0.05) < variance(c, 100, 6, 600, n - 1)
    # tracks per target = tracks per cell x the 6 cells (scans) of each object
    assert (n - 1) * 6 < p["change"]["evaluate.tracks_per_target"] <= n * 6 and p["change"]["now"] == 8


def test_object_variance_beyond_the_data_is_not_reachable():
    d = crossed(np.random.default_rng(3), 12, 2, 4, 0.4, 0.05, 0.0, 0.1)
    p = power_block(d, _primary(), available={"objects": 12, "scans": 2})
    assert p["reading"] == "not reachable with this data" and p["floor_se"] > p["se_needed"]
    assert p["needed"]["tracks_per_cell"] is None and p["needed"]["objects"] > 12


def test_a_large_population_is_already_powered():
    d = crossed(np.random.default_rng(4), 100, 10, 3, 0.01, 0.005, 0.0, 0.05)
    assert power_block(d, _primary())["reading"] == "reached"


def test_the_power_interval_covers_the_planted_power_on_most_populations():
    I, J = 20, 8
    truth = power_at(math.sqrt(0.05 ** 2 / I + 0.02 ** 2 / J + 0.3 ** 2 / (I * J)))
    hits = 0
    for seed in range(20):
        p = power_block(crossed(np.random.default_rng(seed), I, J, 1, 0.05, 0.02, 0.0, 0.3), _primary())
        ci = p["power_ci"]
        assert 0.0 <= ci["ci_low"] <= p["power_now"] <= ci["ci_high"] <= 1.0 and ci["df"] == J - 1
        hits += ci["ci_low"] <= truth <= ci["ci_high"]
    # a 95 % interval on 20 independent populations: 16 or fewer hits has probability < 2 %
    assert hits >= 17, hits
    # the declared record's own degrees of freedom are read where it has them
    rec = {**_primary(), "record": {"df": 3.0}}
    narrow = power_block(crossed(np.random.default_rng(0), I, J, 1, 0.05, 0.02, 0.0, 0.3), rec)["power_ci"]
    assert narrow["df"] == 3.0
