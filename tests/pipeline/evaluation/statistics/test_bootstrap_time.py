"""The bootstrap's time is said up front: one statistic's draws timed on a small run and scaled
linearly, which holds (every resampler array grows linearly with the draws)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from pipeline.evaluation.statistics.resampler import Resampler, draw_seconds


@pytest.mark.parametrize("structure", [[[4] * 12], [[1, 3, 4, 2, 4, 4]]])
def test_scaled_estimate_is_within_a_factor_of_the_measured_time(structure):
    n = 100_000
    est = min(draw_seconds(structure, n) for _ in range(2))
    t0 = time.perf_counter()
    r = Resampler(structure, n, [1])
    r.draws(np.random.default_rng(1).random(r.shape), "mean")
    real = time.perf_counter() - t0
    assert real / 4 < est < real * 4, (est, real)   # timings on a shared machine: a loose factor


def test_estimate_grows_with_the_draws():
    a, b = draw_seconds([[4] * 12], 2_000), draw_seconds([[4] * 12], 1_000_000)
    assert b > 50 * a


def test_evaluate_says_how_long_a_large_bootstrap_takes(tmp_config, capsys):
    from stages.evaluate import check_budget

    cfg = tmp_config({"evaluate": {"bootstrap": 1_000_000}, "run": {"memory_gb": 64}})
    seconds = check_budget(cfg, 12, 4, [4] * 12)
    out = capsys.readouterr().out
    assert seconds > 60 and "evaluate.bootstrap = 1000000" in out and "min" in out
    small = check_budget(tmp_config({"evaluate": {"bootstrap": 2000}}), 12, 4, [4] * 12)
    assert small < seconds / 100


def test_a_bootstrap_over_the_memory_budget_is_refused_with_key_estimate_and_budget(tmp_config):
    from pipeline.infra.budget import MemoryBudgetError
    from stages.evaluate import check_budget

    cfg = tmp_config({"evaluate": {"bootstrap": 1_000_000}, "run": {"memory_gb": 1}})
    with pytest.raises(MemoryBudgetError, match=r"'evaluate.bootstrap' = 1000000: .* needs about .* GiB, over the "
                                                r"memory budget of 1.00 GiB"):
        check_budget(cfg, 12, 4, [4] * 12)
