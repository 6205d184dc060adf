"""The planning metrics per step and per episode, pooled with CIs, and the paired verdicts.

Per step k of an episode: ``correct`` (argmax = truth), ``confident_error`` (max P >= the
confidence on a wrong class), ``nll`` (-ln P(truth)), each as the metric specification defines it
(``pipeline.evaluation.metrics.spec``); per episode ``steps_to_decision``: the first
step with a confident correct decision (P(truth) >= the confidence), budget + 1 when there is
none (a missed or wrong decision costs more than the whole budget). The unit is a (target, start):
its value is the mean over the localization settings; the pooled value is the mean over targets
of their starts' mean, with the hierarchical bootstrap CI over targets, then starts (withheld, with
its reason, under the engine's minimum number of targets: ``design.withheld``). A paired
difference is computed the same way on the per-episode differences (same target, start, setting).

All statistics go through ``_estimate`` (one call site for the statistics engine); the block holds
numbers only: its verdict sentences are rendered in ``reports/main/planning.py``.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import spec as M   # the one definition of each per-step quantity
from pipeline.evaluation.statistics.design import withheld
from pipeline.evaluation.statistics.records import WITHHELD, outcome

# Each step metric is the spec's all-steps metric of that column (its label without ", all steps",
# its direction): planning keeps no list of its own.
SPEC_OF = {"correct": "correct_overall", "confident_error": "confident_error_overall", "nll": "nll_overall"}
STEP_METRICS = {k: (M.METRICS.peek(v).label.rsplit(", ", 1)[0], M.METRICS.peek(v).higher_is_better)
                for k, v in SPEC_OF.items()}
EPISODE_METRICS = {"steps_to_decision": ("steps to a confident correct decision", False)}
AT_STEPS = (3, 5, 10)
COMPARISONS = (("info_gain", "random"), ("info_gain", "fixed"), ("info_gain", "known_pose"))
UNIT = ["target", "start"]


def _estimate(groups, n_boot: int, seed, higher: bool | None = None) -> dict:
    """Mean over groups (targets) of their members' mean (starts), with the statistics engine's
    hierarchical interval (targets, then starts) and, with ``higher``, the one outcome rule's
    verdict. Every call of one block passes the same seed: the engine's draws are shared, so a
    paired difference and its two planners' values are resampled alike."""
    from pipeline.evaluation.statistics.engine import over_groups  # heavy: pandas

    groups = [g for g in groups if len(g)]
    est = over_groups(groups, n_boot, seed)
    est.update(pooling="mean", over=["targets", "starts"],
               n={"targets": len(groups), "starts": int(sum(len(g) for g in groups))})
    # The engine's one rule: too few targets for a calibrated interval -> no CI, no verdict, say why.
    why = withheld({"targets": len(groups)}) if groups else None
    if why:
        est.update(ci_low=None, ci_high=None, withheld=why)
    if higher is not None:
        est["better"] = "higher" if higher else "lower"
        est["outcome"] = WITHHELD if why else outcome(est["ci_low"], est["ci_high"], higher)
    return est


def step_rows(key: dict, log_post: np.ndarray, measured: np.ndarray, nodes: list[str], truth: int,
              confidence: float) -> pd.DataFrame:
    """One row per step of one episode (``key``: target, scan, start, setting, planner)."""
    K = len(log_post)
    node = [""] * K
    for i, k in enumerate(np.flatnonzero(measured)):
        node[k] = nodes[i]
    sv = M.step_values(log_post, truth, is_log=True)      # the grid's per-step values (cell_reduce)
    confident_error = M.confident_mask(sv["confidence"], sv["correct"], confidence)
    return pd.DataFrame({**{k: [v] * K for k, v in key.items()}, "step": np.arange(1, K + 1), "node": node,
                         "measured": measured, "p_truth": sv["p_truth"],
                         "correct": sv["correct"].astype(float), "confident_error": confident_error.astype(float),
                         "nll": sv["nll"]})


def episode_values(table: pd.DataFrame, budget: int, confidence: float) -> pd.DataFrame:
    """Per episode: steps_to_decision and each step metric at the steps of ``AT_STEPS``."""
    keys = UNIT + ["setting", "planner"]
    hit = table[(table["correct"] > 0) & (table["p_truth"] >= confidence)]
    first = hit.groupby(keys)["step"].min()
    ep = table.groupby(keys).size().rename("n").reset_index()[keys]
    ep["steps_to_decision"] = ep.set_index(keys).index.map(first).to_numpy(float)
    ep["steps_to_decision"] = ep["steps_to_decision"].fillna(budget + 1.0)
    for k in at_steps(budget):
        at = table[table["step"] == k].set_index(keys)
        for m in STEP_METRICS:
            ep[f"{m}_at_{k}"] = ep.set_index(keys).index.map(at[m]).to_numpy(float)
    return ep


def _groups(units: pd.DataFrame, col: str) -> list[np.ndarray]:
    return [g[col].to_numpy(float) for _, g in units.groupby("target", sort=True)]


def _units(df: pd.DataFrame, cols) -> pd.DataFrame:
    return df.groupby(UNIT, sort=True)[list(cols)].mean().reset_index()


def at_steps(budget: int) -> list[int]:
    """The steps of ``AT_STEPS`` the budget reaches."""
    return [k for k in AT_STEPS if k <= budget]


def pooled_metrics(budget: int) -> dict[str, tuple[str, bool]]:
    """The episode-level keys of the pooled table: {key: (label, higher_is_better)}."""
    out = dict(EPISODE_METRICS)
    for k in at_steps(budget):
        for m, (label, hi) in STEP_METRICS.items():
            out[f"{m}_at_{k}"] = (f"{label} at step {k}", hi)
    return out


def planning_block(table: pd.DataFrame, planners, budget: int, confidence: float, n_boot: int, seed: int) -> dict:
    """The summary.json ``planning`` block: curves per step, pooled table, paired verdicts."""
    ep = episode_values(table, budget, confidence)
    metrics = pooled_metrics(budget)
    n_t, n_u = ep["target"].nunique(), len(ep.drop_duplicates(UNIT))
    settings = sorted(ep["setting"].unique())
    scope = f"{n_t} targets x {n_u} starts x {len(settings)} localization settings"
    curves, pooled = {}, {}
    draw_seed = [seed, 10]   # one set of draws for the whole block (the engine caches it)
    for p in planners:
        sub = table[table["planner"] == p]
        curves[p] = {m: [] for m in STEP_METRICS}
        for k in range(1, budget + 1):
            u = _units(sub[sub["step"] == k], STEP_METRICS)
            for m in STEP_METRICS:
                curves[p][m].append(_estimate(_groups(u, m), n_boot, draw_seed))
        u = _units(ep[ep["planner"] == p], metrics)
        pooled[p] = {m: _estimate(_groups(u, m), n_boot, draw_seed) for m in metrics}
    paired = {}
    keys = UNIT + ["setting"]
    for a, b in COMPARISONS:
        if a not in planners or b not in planners:
            continue
        da = ep[ep["planner"] == a].set_index(keys).sort_index()
        db = ep[ep["planner"] == b].set_index(keys).sort_index()
        diff = _units((da[list(metrics)] - db[list(metrics)]).reset_index(), metrics)
        block = paired[f"{a}-{b}"] = {}
        for m, (_label, higher) in metrics.items():
            block[m] = _estimate(_groups(diff, m), n_boot, draw_seed, higher)
    return {"planners": list(planners), "settings": settings, "budget": budget, "confidence": confidence,
            "at_steps": at_steps(budget), "n_targets": int(n_t), "n_starts": int(n_u), "scope": scope,
            "curves": curves, "pooled": pooled, "paired": paired,
            "labels": {m: lab for m, (lab, _) in {**STEP_METRICS, **metrics}.items()}}
