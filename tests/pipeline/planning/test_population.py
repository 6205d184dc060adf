"""The planning population on hand-built worlds: tasks, the per-step table, the pooled block with
its CIs and verdicts. The same episodes through Ray: tests/stages/test_ray.py (the evaluate stage's
planning.parquet, local and on Ray)."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.planning.evaluation import episode_table
from pipeline.planning.population import LocSetting, Task, run_task
from pipeline.planning.summary import episode_values, planning_block, step_rows
from tests.pipeline.planning.ring import models, ring_world

SETTINGS = (LocSetting("biased", (-0.2, 0.1), 0.0, 0.2, 6), LocSetting("randomized", (0.0, 0.0), 0.2, 0.2, 6))


def tasks(n_targets=3, starts=2):
    out = []
    for t in range(n_targets):
        for s in range(starts):
            w = ring_world(truth=t % 2, seed=10 * t + s, chords=True)
            w = type(w)(**{**w.__dict__, "target": f"obj{t}"})
            out.append(Task(w, s, SETTINGS, ("info_gain", "known_pose", "random", "fixed", "orbit", "hindsight"),
                            5, 2, 0.9, 32, 0, 1e-6))
    return out


def banks():
    return {"default": models()}


def test_steps_to_decision_and_step_metrics():
    lp = np.log(np.array([[0.6, 0.4], [0.3, 0.7], [0.95, 0.05], [0.95, 0.05]]))
    key = {"target": "t", "scan": "s", "start": 0, "setting": "biased", "planner": "p"}
    rows = step_rows(key, lp, np.array([1, 1, 1, 0], bool), ["a", "b", "c"], 0, 0.9)
    assert list(rows["correct"]) == [1, 0, 1, 1] and list(rows["node"]) == ["a", "b", "c", ""]
    np.testing.assert_allclose(rows["nll"], -lp[:, 0])
    ep = episode_values(rows, budget=4, confidence=0.9)
    assert ep["steps_to_decision"].iloc[0] == 3
    wrong = step_rows(key, lp[:, ::-1], np.ones(4, bool), list("abcd"), 0, 0.9)
    assert episode_values(wrong, 4, 0.9)["steps_to_decision"].iloc[0] == 5      # none: budget + 1
    assert wrong["confident_error"].tolist() == [0, 0, 1, 1]


def test_planning_and_the_grid_give_the_same_values_for_the_same_posterior():
    """One episode's posteriors (K, C) through planning's step table and through the grid's route
    (the spec's step values reduced by its all-steps metrics, as ``cell_reduce`` does): equal."""
    from pipeline.evaluation.metrics import spec as M
    from pipeline.planning.summary import SPEC_OF, STEP_METRICS

    rng = np.random.default_rng(4)
    lp = np.log(rng.dirichlet([0.3] * 4, size=9))                   # some confident, some wrong
    lp[2] = np.log([0.91, 0.03, 0.03, 0.03])                        # a confident error (truth 1)
    key = {"target": "t", "scan": "s", "start": 0, "setting": "biased", "planner": "p"}
    rows = step_rows(key, lp, np.ones(9, bool), list("abcdefghi"), 1, 0.9)
    grid = M.posterior_metrics(lp[None], 1, params=M.Params(0.9, 10), is_log=True)
    assert rows["confident_error"].sum() >= 1
    for m, spec_key in SPEC_OF.items():
        assert rows[m].mean() == pytest.approx(grid[spec_key], rel=1e-12, abs=1e-12), m
        assert STEP_METRICS[m][1] == M.higher_is_better(spec_key)


def test_population_block_pools_over_targets_with_cis_and_verdicts():
    ts = tasks()
    results = [run_task(banks(), t) for t in ts]
    table, times = episode_table(ts, results)
    assert len(table) == len(ts) * 2 * 6 * 5 and len(times) > 0
    block = planning_block(table, ts[0].planners, 5, 0.9, 200, 0)
    assert block["n_targets"] == 3 and block["n_starts"] == 6
    for p in ts[0].planners:
        e = block["pooled"][p]["steps_to_decision"]
        # 3 targets: under the engine's minimum, so no interval and the reason (the one rule)
        assert e["ci_low"] is None and e["ci_high"] is None and "3 targets" in e["withheld"]
        assert len(block["curves"][p]["correct"]) == 5
    # the pooled value is the mean over targets of the mean over their starts (and settings)
    ep = episode_values(table, 5, 0.9)
    sub = ep[ep["planner"] == "random"]
    want = sub.groupby(["target", "start"])["correct_at_3"].mean().groupby("target").mean().mean()
    assert block["pooled"]["random"]["correct_at_3"]["value"] == pytest.approx(want)
    assert sum(m == "steps_to_decision" or m.startswith("correct_at") for e in block["paired"].values() for m in e) == 3 * 3
    assert all(e[m]["outcome"] == "withheld" for e in block["paired"].values() for m in e)
    assert "correct_at_10" not in block["pooled"]["random"]


def test_planning_estimates_get_an_interval_and_a_verdict_from_eight_targets_on():
    from pipeline.planning.summary import _estimate

    rng = np.random.default_rng(0)
    few = _estimate([rng.normal(1.0, 0.1, 3) for _ in range(7)], 400, [0, 10], higher=True)
    assert few["ci_low"] is None and few["outcome"] == "withheld" and "7 targets" in few["withheld"]
    enough = _estimate([rng.normal(1.0, 0.1, 3) for _ in range(8)], 400, [0, 10], higher=True)
    assert enough["ci_low"] <= enough["value"] <= enough["ci_high"] and "withheld" not in enough
    assert enough["outcome"] == "better"          # every difference near +1: the interval excludes 0


def test_hindsight_and_info_gain_beat_random_on_the_separating_world():
    ts = tasks(n_targets=4, starts=2)
    block = planning_block(episode_table(ts, [run_task(banks(), t) for t in ts])[0], ts[0].planners, 5, 0.9, 200, 0)
    p = block["pooled"]
    assert p["info_gain"]["steps_to_decision"]["value"] < p["random"]["steps_to_decision"]["value"]
    assert p["hindsight"]["steps_to_decision"]["value"] <= p["info_gain"]["steps_to_decision"]["value"]


def _same(a, b):
    for (sa, pa, ea), (sb, pb, eb) in zip(a, b):
        assert (sa, pa, ea.nodes) == (sb, pb, eb.nodes)
        np.testing.assert_array_equal(ea.log_post, eb.log_post)


def test_run_task_is_deterministic():
    t = tasks(1, 1)[0]
    _same(run_task(banks(), t), run_task(banks(), t))
