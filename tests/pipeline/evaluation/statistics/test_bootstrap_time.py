"""The bootstrap's time is said up front: one statistic's draws timed on a small run and scaled
linearly, which holds (every resampler array grows linearly with the draws). How close the estimate
comes to the measured time is a timing: `python tests/bench/bench_bootstrap_estimate.py`."""
from __future__ import annotations

import pytest

from pipeline.evaluation.statistics.resampler import draw_seconds


def test_estimate_grows_with_the_draws():
    a, b = draw_seconds([[4] * 12], 2_000), draw_seconds([[4] * 12], 1_000_000)
    assert b > 50 * a


def test_evaluate_says_how_long_a_large_bootstrap_takes(tmp_config, capsys):
    from stages.evaluate import check_budget

    # no limit on the bootstrap's time, nor on the stage's (the cost model adds the two up)
    cfg = tmp_config({"evaluate": {"bootstrap": 1_000_000},
                      "run": {"memory_gb": 64, "max_bootstrap_minutes": 0, "max_minutes": 0}})
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


def _fixed_draw_time(monkeypatch, per_statistic: float):
    """A machine on which one interval's draws take ``per_statistic`` seconds. Patched where
    ``check_budget`` looks the name up (``stages.evaluate`` binds it at import): patching the
    resampler's attribute left the real timing in place once ``stages.evaluate`` was imported,
    and bound the stand-in for the whole process where this test imported it first."""
    import stages.evaluate

    monkeypatch.setattr(stages.evaluate, "draw_seconds", lambda structure, n_boot, trial=20_000: per_statistic)


@pytest.mark.parametrize("limit_min, refused", [(1, True), (10_000, False), (0, False)])
def test_a_bootstrap_that_fits_memory_but_not_the_time_limit_is_refused(tmp_config, monkeypatch, limit_min, refused):
    from pipeline.infra.config import ConfigError
    from stages.evaluate import check_budget

    _fixed_draw_time(monkeypatch, 0.5)  # > 1000 intervals: over 8 min, under a week
    cfg = tmp_config({"evaluate": {"bootstrap": 300_000},
                      "run": {"memory_gb": 64, "max_bootstrap_minutes": limit_min}})
    if not refused:
        seconds = check_budget(cfg, 12, 4, [4] * 12)
        assert 60 < seconds < 60 * 10_000
        assert (seconds / 0.5).is_integer()   # the intervals times the stand-in's draw time: no draw was timed
        return
    with pytest.raises(ConfigError) as e:
        check_budget(cfg, 12, 4, [4] * 12)
    msg = str(e.value)
    seconds = int(msg.split("would take about ")[1].split(" s")[0])
    assert "'evaluate.bootstrap' = 300000" in msg and seconds > 60
    assert "'run.max_bootstrap_minutes' = 1" in msg and "raise 'run.max_bootstrap_minutes'" in msg


def test_the_time_limit_is_measured_on_this_machine(tmp_config):
    """No stand-in timing: 200000 draws for each of 1000+ intervals over 30 targets take longer
    than a few seconds anywhere; the default bootstrap stays far under the default limit."""
    from pipeline.infra.config import ConfigError
    from stages.evaluate import check_budget

    with pytest.raises(ConfigError, match=r"'evaluate.bootstrap' = 200000: .* s \(.* min; scaled from a timed run"):
        check_budget(tmp_config({"evaluate": {"bootstrap": 200_000},
                                 "run": {"memory_gb": 64, "max_bootstrap_minutes": 0.05}}), 30, 4, [4] * 30)
    assert check_budget(tmp_config({"run": {"memory_gb": 64}}), 30, 4, [4] * 30) < 60 * 60


def test_memory_is_checked_before_the_time(tmp_config, monkeypatch):
    """A bootstrap over both limits is refused for its memory, without timing a draw."""
    import stages.evaluate
    from pipeline.infra.budget import MemoryBudgetError
    from stages.evaluate import check_budget

    monkeypatch.setattr(stages.evaluate, "draw_seconds", lambda *a, **k: pytest.fail("timed a draw"))
    cfg = tmp_config({"evaluate": {"bootstrap": 400_000}, "run": {"memory_gb": 2, "max_bootstrap_minutes": 1}})
    with pytest.raises(MemoryBudgetError, match=r"'evaluate.bootstrap' = 400000: .* 40 targets x up to 6 tracks .* "
                                                 r"over the memory budget of 2.00 GiB .*raise run.memory_gb"):
        check_budget(cfg, 40, 6, [6] * 40)
