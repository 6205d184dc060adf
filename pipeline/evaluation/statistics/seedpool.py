"""Pooling classifier training runs (seeds) into the population statistics.

A seed's CIs cover targets and tracks, not the training run: pooled levels move between seeds far
more than those CIs say (README, "Seed study"). Here a seed is a third level of the hierarchical
bootstrap: resample seeds with replacement, then, independently for every drawn seed, its targets
and the tracks within them. The point value is the mean over seeds of each seed's pooled statistic
(the mean over targets for bounded metrics; the median over targets, ``robust.STATISTIC``, for
unbounded ones), so every seed weighs the same.

Input per seed: ``summary.json``'s ``population.cells`` (one entry per (target, track, setting)
with every method's cell metrics).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from pipeline.evaluation.statistics import robust as R

STAT_UNBOUNDED = "median"


def _stat_name(metric: str) -> str:
    return STAT_UNBOUNDED if metric.startswith(("log10_mgr", "nll")) else "mean"


def track_groups(cells: Sequence[Mapping], value) -> tuple[list[str], list[np.ndarray]]:
    """Targets and, per target, its tracks' values (mean over settings) of ``value(cell values)``,
    skipping cells where it is None."""
    per: dict[str, dict[int, list[float]]] = {}
    for c in cells:
        v = value(c.get("values") or {})
        if v is None or not np.isfinite(v):
            continue
        per.setdefault(str(c["target"]), {}).setdefault(int(c["track"]), []).append(float(v))
    names = sorted(per)
    return names, [np.array([np.mean(per[t][k]) for k in sorted(per[t])]) for t in names]


def _seed_draws(groups, n: int, seed, stat: str) -> tuple[float, np.ndarray]:
    f = (lambda a: np.median(a, axis=-1)) if stat == "median" else (lambda a: np.mean(a, axis=-1))
    value = float(f(np.array([g.mean() for g in groups])))
    rs = R.Resample([len(g) for g in groups], n, seed)
    return value, f(rs.slot_means(R.pad(groups)))


def pooled_over_seeds(per_seed: Sequence[list[np.ndarray]], n_boot: int, seed, stat: str) -> dict:
    """Mean over seeds of each seed's ``stat`` over targets, with a seeds -> targets -> tracks
    bootstrap 95 % CI. ``per_seed``: for each seed, its targets' track-value arrays."""
    per_seed = [g for g in per_seed if g]
    if not per_seed:
        return {"value": float("nan"), "ci_low": float("nan"), "ci_high": float("nan"), "n_seeds": 0}
    S = len(per_seed)
    vals, draws = [], []
    for i, g in enumerate(per_seed):
        v, d = _seed_draws(g, n_boot * S, [*np.atleast_1d(seed), 20, i], stat)
        vals.append(v)
        draws.append(d.reshape(n_boot, S))           # an independent inner draw for every slot
    draws = np.stack(draws)                          # (S seeds, B, S slots)
    pick = np.random.default_rng([*np.atleast_1d(seed), 21]).integers(0, S, size=(n_boot, S))
    boot = draws[pick, np.arange(n_boot)[:, None], np.arange(S)[None, :]].mean(axis=1)
    return {**R.estimate(float(np.mean(vals)), boot), "n_seeds": S,
            "per_seed": [float(v) for v in vals]}


def seed_pooled(cells_by_seed: Mapping[str, Sequence[Mapping]], methods: Sequence[str], metrics: Sequence[str],
                comparisons, n_boot: int, seed: int = 0) -> dict:
    """{"pooled": {method: {metric: est}}, "paired": {key: {metric: est}}, "verdict_table": rows,
    "verdict": sentences} over every seed's cells."""
    from pipeline.evaluation.metrics.labels import METHOD_SHORT
    from pipeline.evaluation.metrics.spec import METRICS, metric_label

    seeds = sorted(cells_by_seed)
    out: dict = {"seeds": seeds, "pooled": {}, "paired": {}, "verdict": [], "verdict_table": [],
                 "statistic": {k: ("mean over seeds of the median over targets" if _stat_name(k) == "median"
                                   else "mean over seeds of the mean over targets") for k in metrics}}
    for mi, m in enumerate(methods):
        for ki, k in enumerate(metrics):
            groups = [track_groups(cells_by_seed[s], lambda v, m=m, k=k: (v.get(m) or {}).get(k))[1] for s in seeds]
            out["pooled"].setdefault(m, {})[k] = pooled_over_seeds(groups, n_boot, [seed, mi, ki], _stat_name(k))
    for a, b in comparisons:
        key = f"{a}-{b}"
        for ki, k in enumerate(metrics):
            def diff(v, k=k):
                x, y = (v.get(a) or {}).get(k), (v.get(b) or {}).get(k)
                return None if x is None or y is None else x - y
            groups = [track_groups(cells_by_seed[s], diff)[1] for s in seeds]
            if not any(groups):
                continue
            est = pooled_over_seeds(groups, n_boot, [seed, 99, ki], _stat_name(k))
            out["paired"].setdefault(key, {})[k] = est
            higher = METRICS[k].higher_is_better if k in METRICS else False
            res = R.outcome(est, higher)
            phrase = {"better": "is better than", "worse": "is worse than",
                      "not distinguishable": "is not distinguishable from"}[res]
            spread = ", ".join(f"{v:+.3g}" for v in est["per_seed"])
            out["verdict"].append(
                f"{METHOD_SHORT.get(a, a)} {phrase} {METHOD_SHORT.get(b, b)} on {metric_label(k)} "
                f"({out['statistic'][k]} of the differences {est['value']:+.3g}, 95 % CI [{est['ci_low']:+.3g}, "
                f"{est['ci_high']:+.3g}] over {len(seeds)} seeds, their targets and tracks; per seed: {spread}).")
            out["verdict_table"].append({"comparison": key, "metric": k, "outcome": res, "value": est["value"],
                                         "ci_low": est["ci_low"], "ci_high": est["ci_high"]})
    return out
