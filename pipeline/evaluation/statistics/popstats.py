"""Population statistics: values with bootstrap confidence intervals, paired method differences,
and the verdict sentences computed from those intervals.

The unit is a cell: one (target, track, setting), whose metric is computed over that cell's
realizations (a correct ratio, a percentile of log10 MGR, ...). A track's value is the mean over
its settings; a target's value the mean over its tracks; the pooled value the mean over targets,
so every target weighs the same whatever its number of tracks. Realizations vary only the
localization noise on a fixed track: the intervals come from resampling what a new study would
change, targets and tracks. The bootstrap is hierarchical (targets with replacement, then each
drawn target's tracks with replacement) and uses percentile intervals.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics.labels import METHOD_SHORT, comparison_key
from pipeline.evaluation.metrics.spec import METRICS, percentile
from pipeline.evaluation.statistics.robust import outcome  # noqa: F401 (one verdict rule; re-exported)


def wilson_interval(k: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson 95 % interval of a proportion k/n (a held-out accuracy: over the images drawn)."""
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)

LEVEL = 0.95


def _boot_means(x: np.ndarray, n_boot: int, n_slots: int, rng: np.random.Generator) -> np.ndarray:
    """Means of ``x`` resampled with replacement: (n_boot, n_slots) independent draws."""
    idx = rng.integers(0, len(x), size=(n_boot, n_slots, len(x)))
    return x[idx].mean(axis=-1)


def _interval(samples: np.ndarray) -> tuple[float, float]:
    lo, hi = percentile(samples, [50 * (1 - LEVEL), 50 * (1 + LEVEL)])
    return float(lo), float(hi)


def _estimate(value: float, samples: np.ndarray | None) -> dict[str, float]:
    lo, hi = (value, value) if samples is None else _interval(samples)
    # Percentiles of a resampled mean of identical values can differ from it in the last bit.
    return {"value": float(value), "ci_low": min(float(lo), float(value)), "ci_high": max(float(hi), float(value))}


def hierarchical(groups: Sequence[np.ndarray], n_boot: int, seed) -> dict[str, float]:
    """Mean over groups of the group means, with a two-level bootstrap CI (groups, then members).

    Each bootstrap draws T groups with replacement and, for every drawn slot independently, that
    group's members with replacement (a group drawn twice gets two member resamples).
    """
    groups = [np.asarray(g, float) for g in groups if len(g)]
    if not groups:
        return {"value": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    rng = np.random.default_rng(seed)
    T = len(groups)
    sizes = np.array([len(g) for g in groups])
    width = int(sizes.max())
    padded = np.zeros((T, width))
    for t, g in enumerate(groups):
        padded[t, : len(g)] = g
    value = float(np.mean([g.mean() for g in groups]))
    pick = rng.integers(0, T, size=(n_boot, T))                                   # drawn groups
    n = sizes[pick]                                                               # (B, T)
    members = (rng.random((n_boot, T, width)) * n[..., None]).astype(np.int64)    # in [0, n)
    used = np.arange(width)[None, None, :] < n[..., None]
    draws = np.where(used, padded[pick[..., None], members], 0.0)
    boot = (draws.sum(axis=-1) / n).mean(axis=1)
    return _estimate(value, boot)


def within(group: np.ndarray, n_boot: int, seed) -> dict[str, float]:
    """Mean of one group's members with a bootstrap CI over its members."""
    g = np.asarray(group, float)
    if len(g) < 2:  # one member says nothing about the spread: no interval
        return {"value": float(g.mean()) if len(g) else float("nan"), "ci_low": float("nan"),
                "ci_high": float("nan")}
    return _estimate(float(g.mean()), _boot_means(g, n_boot, 1, np.random.default_rng(seed))[:, 0])


def track_values(cells: pd.DataFrame, metrics: Sequence[str]) -> pd.DataFrame:
    """Cell rows (target, track, setting, method, metrics...) -> one row per (method, target, track):
    the mean over the track's settings."""
    return cells.groupby(["method", "target", "track"], sort=True)[list(metrics)].mean().reset_index()


def _groups(tv: pd.DataFrame, metric: str) -> tuple[list[str], list[np.ndarray]]:
    by = {t: g[metric].to_numpy(float) for t, g in tv.groupby("target", sort=True)}
    return list(by), list(by.values())


def summarize_methods(cells: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str], n_boot: int,
                      seed: int, per_target: bool = True) -> tuple[dict, dict]:
    """Pooled and per-target values with CIs: ({method: {metric: est}}, {target: {method: {metric: est}}})."""
    tv = track_values(cells, metrics)
    want_targets, pooled, targets = per_target, {}, {}
    for mi, m in enumerate(methods):
        sub = tv[tv["method"] == m]
        pooled[m] = {}
        for ki, k in enumerate(metrics):
            names, groups = _groups(sub, k)
            pooled[m][k] = hierarchical(groups, n_boot, [seed, 0, ki])
            for ti, (t, g) in enumerate(zip(names, groups) if want_targets else ()):
                targets.setdefault(t, {}).setdefault(m, {})[k] = within(g, n_boot, [seed, 1, ti, ki])
    return pooled, targets


def paired_differences(cells: pd.DataFrame, method: str, baseline: str, metrics: Sequence[str], n_boot: int,
                       seed: int, per_target: bool = True) -> tuple[dict, dict]:
    """``method - baseline`` on the same cells, pooled and per target, with CIs, plus the share of
    cells each wins. Returns ({metric: est + wins/losses/n_cells/better}, {target: {metric: est}})."""
    keys = ["target", "track", "setting"]
    a = cells[cells["method"] == method].set_index(keys).sort_index()
    b = cells[cells["method"] == baseline].set_index(keys).sort_index()
    if not a.index.equals(b.index):
        raise ValueError(f"paired_differences: {method} and {baseline} were not run on the same cells")
    diff = (a[list(metrics)] - b[list(metrics)]).reset_index()
    diff["method"] = "diff"
    tv = track_values(diff, metrics)
    want_targets, pooled, per_target = per_target, {}, {}
    for ki, k in enumerate(metrics):
        higher = METRICS[k].higher_is_better
        d = diff[k].to_numpy(float)
        names, groups = _groups(tv, k)
        est = hierarchical(groups, n_boot, [seed, 2, ki])
        wins = d > 0 if higher else d < 0
        losses = d < 0 if higher else d > 0
        pooled[k] = {**est, "wins": float(wins.mean()), "losses": float(losses.mean()), "n_cells": int(len(d)),
                     "better": "higher" if higher else "lower"}
        for ti, (t, g) in enumerate(zip(names, groups) if want_targets else ()):
            per_target.setdefault(t, {})[k] = within(g, n_boot, [seed, 3, ti, ki])
    return pooled, per_target


def saturation(cells: pd.DataFrame, method: str, baseline: str, metric: str) -> tuple[int, int]:
    """(cells where both methods are at the metric's best value, cells where both are at its worst):
    those cannot tell the methods apart (a ceiling or floor effect; ``Metric.best``/``worst``)."""
    keys = ["target", "track", "setting"]
    a = cells[cells["method"] == method].set_index(keys)[metric]
    b = cells[cells["method"] == baseline].set_index(keys)[metric].reindex(a.index)
    best, worst = METRICS[metric].best, METRICS[metric].worst
    both_best = int(((np.abs(a - best) < 1e-12) & (np.abs(b - best) < 1e-12)).sum()) if best is not None else 0
    both_worst = int(((np.abs(a - worst) < 1e-12) & (np.abs(b - worst) < 1e-12)).sum()) if worst is not None else 0
    return both_best, both_worst


_PHRASE = {"better": "is better than", "worse": "is worse than", "not distinguishable": "is not distinguishable from"}


def _num(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{x:+.3g}" if x else "0"


def verdict(cells: pd.DataFrame, paired: dict[str, dict], scope: str) -> tuple[list[str], list[dict]]:
    """Sentences and table rows, one per (comparison, metric), from the paired CIs alone.

    ``paired`` maps "method-baseline" to ``paired_differences``' pooled dict; ``scope`` says what
    the population is (e.g. "6 targets x 8 tracks x 4 settings").
    """
    sentences, rows = [], []
    for key, per_metric in paired.items():
        method, baseline = key.split("-", 1)
        for metric, est in per_metric.items():
            label, higher = METRICS[metric].label, METRICS[metric].higher_is_better
            res = outcome(est, higher)
            top, bottom = saturation(cells, method, baseline, metric)
            n = est["n_cells"]
            text = (f"{METHOD_SHORT.get(method, method)} {_PHRASE[res]} {METHOD_SHORT.get(baseline, baseline)} on "
                    f"{label} (difference {_num(est['value'])}, 95 % CI [{_num(est['ci_low'])}, {_num(est['ci_high'])}], "
                    f"over {scope}; better in {est['wins']:.0%} of cells, worse in {est['losses']:.0%})")
            sat = []
            if top:
                sat.append(f"{top} of {n} cells had both methods at the best possible value")
            if bottom:
                sat.append(f"{bottom} of {n} at the worst")
            if sat:
                text += "; " + " and ".join(sat)
            sentences.append(text + ".")
            rows.append({"comparison": key, "metric": metric, "outcome": res, "value": est["value"],
                         "ci_low": est["ci_low"], "ci_high": est["ci_high"], "n_cells": n,
                         "ceiling_cells": top, "floor_cells": bottom})
    return sentences, rows


def population_block(cells: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str],
                     comparisons: Sequence[tuple[str, str]], n_boot: int, seed: int, scope: str,
                     per_target: bool = True) -> dict:
    """Everything the summary holds for one population of cells: pooled, per target (unless
    ``per_target`` is false), paired, verdict."""
    pooled, per_target_est = summarize_methods(cells, methods, metrics, n_boot, seed, per_target)
    paired, paired_t = {}, {}
    for m, b in comparisons:
        if m in methods and b in methods:
            key = comparison_key(m, b)
            paired[key], paired_t[key] = paired_differences(cells, m, b, metrics, n_boot, seed, per_target)
    sentences, table = verdict(cells, paired, scope)
    return {"pooled": pooled, "per_target": per_target_est, "paired": paired, "paired_per_target": paired_t,
            "verdict": sentences, "verdict_table": table}
