"""The population block with calibration metrics, robust statistics and caveated verdicts.

``full_block`` extends ``popstats.population_block`` (means with hierarchical bootstrap CIs):
- the pooled ECE (``pooled_calibration``) joins ``pooled``, ``per_target`` and ``paired``;
- every unbounded metric (log10 MGR percentiles, NLL) gets a ``robust`` entry: the median over
  targets (``robust.STATISTIC``, docs/design.md "Robust pooling") per method and per paired
  difference, with its CI and the leave-one-target-out range; the verdict for these metrics is
  decided by the robust CI, not the mean's;
- every verdict sentence gives the leave-one-target-out range of its statistic and names the
  targets whose removal alone changes the outcome; a sentence that calls a method better (or
  worse) while it loses (wins) more cells than it wins (loses) says so.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.statistics import robust as R
from pipeline.evaluation.metrics.labels import METHOD_SHORT, comparison_key
from pipeline.evaluation.metrics.spec import METRICS, higher_is_better, metric_label
from pipeline.evaluation.statistics.popstats import population_block, saturation, track_values

UNBOUNDED_PREFIXES = ("log10_mgr", "nll")


def is_unbounded(metric: str) -> bool:
    return metric.startswith(UNBOUNDED_PREFIXES)


def _higher(metric: str) -> bool:
    return higher_is_better(metric)


def _label(metric: str) -> str:
    return metric_label(metric)


def _target_groups(tv: pd.DataFrame, metric: str) -> tuple[list[str], list[np.ndarray]]:
    names, groups = [], []
    for t, g in tv.groupby("target", sort=True):
        names.append(str(t))
        groups.append(g[metric].to_numpy(float))
    return names, groups


def paired_groups(cells: pd.DataFrame, a: str, b: str, metrics: Sequence[str]) -> pd.DataFrame:
    """Track values of the paired differences a - b (same cells)."""
    keys = ["target", "track", "setting"]
    x = cells[cells["method"] == a].set_index(keys).sort_index()
    y = cells[cells["method"] == b].set_index(keys).sort_index()
    d = (x[list(metrics)] - y[list(metrics)]).reset_index()
    d["method"] = "diff"
    return track_values(d, metrics)


def robust_stats(cells: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str], comparisons,
                 n_boot: int, seed: int, loto: bool = True) -> dict:
    """{metric: {"statistic", "pooled": {method: est}, "paired": {key: est + LOTO}}} for unbounded metrics."""
    out = {}
    tv = track_values(cells, metrics)
    diffs = {(a, b): paired_groups(cells, a, b, metrics) for a, b in comparisons if a in methods and b in methods}
    for ki, k in enumerate(metrics):
        entry = {"statistic": R.STATISTIC, "pooled": {}, "paired": {}}
        for mi, m in enumerate(methods):
            names, groups = _target_groups(tv[tv["method"] == m], k)
            if groups:
                entry["pooled"][m] = R.pooled(groups, n_boot, [seed, 10])
        for a, b in comparisons:
            if a not in methods or b not in methods:
                continue
            names, groups = _target_groups(diffs[(a, b)], k)
            sd = [seed, 11]
            est = R.pooled(groups, n_boot, sd)
            if loto:
                est.update(R.leave_one_out(names, groups, n_boot, sd, "median", _higher(k)))
            entry["paired"][comparison_key(a, b)] = est
        out[k] = entry
    return out


def _num(x: float) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:+.3g}" if x else "0"


_PHRASE = {"better": "is better than", "worse": "is worse than", "not distinguishable": "is not distinguishable from"}


def verdict(cells: pd.DataFrame, paired: dict, robust: dict, scope: str, n_boot: int, seed: int,
            loto: bool = True) -> tuple[list[str], list[dict]]:
    """One sentence and table row per (comparison, metric). Unbounded metrics are decided by the
    robust statistic; bounded ones by the mean (with its own leave-one-target-out range)."""
    sentences, rows = [], []
    for key, per_metric in paired.items():
        method, baseline = key.split("-", 1)
        bounded = [m for m in per_metric if m in METRICS and m not in robust]
        diffs = paired_groups(cells, method, baseline, bounded) if (loto and bounded) else None
        for ki, (metric, mean_est) in enumerate(per_metric.items()):
            higher = _higher(metric)
            rob = robust.get(metric, {}).get("paired", {}).get(key)
            est = dict(rob) if rob is not None else dict(mean_est)
            if rob is None and loto and "loto_min" not in est and metric in METRICS:
                names, groups = _target_groups(diffs, metric)
                est.update(R.leave_one_out(names, groups, n_boot, [seed, 12], "mean", higher))
            res = R.outcome(est, higher)
            stat = (f"median over targets of the target differences {_num(est['value'])}" if rob is not None
                    else f"difference {_num(est['value'])}")
            unit = "targets" if mean_est.get("unit") == "targets" else "cells"
            wins, losses = mean_est.get("wins", float("nan")), mean_est.get("losses", float("nan"))
            text = (f"{METHOD_SHORT.get(method, method)} {_PHRASE[res]} {METHOD_SHORT.get(baseline, baseline)} on "
                    f"{_label(metric)} ({stat}, 95 % CI [{_num(est['ci_low'])}, {_num(est['ci_high'])}], over {scope}")
            if np.isfinite(est.get("loto_min", float("nan"))):
                text += f"; leaving one target out: {_num(est['loto_min'])} to {_num(est['loto_max'])}"
            text += f"; better in {wins:.0%} of {unit}, worse in {losses:.0%})"
            notes = []
            flips = est.get("loto_flips") or []
            if flips:
                to = est.get("loto_flip_outcomes") or {}
                named = [f"{f} ({to[f]})" if f in to else f for f in flips[:3]]
                notes.append(f"dropping {' or '.join(named)}{' (or another of ' + str(len(flips)) + ')' if len(flips) > 3 else ''}"
                             " alone changes the outcome (to the one in brackets)")
            if res == "better" and losses > wins:
                notes.append(f"it loses more {unit} than it wins" + (" (the majority)" if losses > 0.5 else ""))
            if res == "worse" and wins > losses:
                notes.append(f"it wins more {unit} than it loses" + (" (the majority)" if wins > 0.5 else ""))
            top = bottom = 0
            if unit == "cells" and metric in METRICS:
                top, bottom = saturation(cells, method, baseline, metric)
                n = mean_est.get("n_cells", 0)
                if top:
                    notes.append(f"{top} of {n} cells had both methods at the best possible value")
                if bottom:
                    notes.append(f"{bottom} of {n} at the worst")
            sentences.append(text + ("; " + "; ".join(notes) if notes else "") + ".")
            rows.append({"comparison": key, "metric": metric, "outcome": res, "statistic": (
                R.STATISTIC if rob is not None else "mean over targets"), "value": est["value"],
                "ci_low": est["ci_low"], "ci_high": est["ci_high"], "mean_value": mean_est["value"],
                "n_cells": mean_est.get("n_cells"), "wins": wins, "losses": losses,
                "loto_min": est.get("loto_min"), "loto_max": est.get("loto_max"), "loto_flips": list(flips),
                "ceiling_cells": top, "floor_cells": bottom})
    return sentences, rows


def full_block(cells: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str], comparisons,
               n_boot: int, seed: int, scope: str, *, ece: dict | None = None, per_target: bool = True,
               loto: bool = True) -> dict:
    """``population_block`` plus the pooled ECE, the robust statistics and the caveated verdict."""
    block = population_block(cells, methods, metrics, comparisons, n_boot, seed, scope, per_target)
    for key in ("pooled", "per_target", "paired", "paired_per_target"):
        for name, sub in ((ece or {}).get(key) or {}).items():
            if key in ("per_target", "paired_per_target"):
                for inner, vals in sub.items():
                    block[key].setdefault(name, {}).setdefault(inner, {}).update(vals)
            else:
                block[key].setdefault(name, {}).update(sub)
    if ece and ece.get("reliability"):
        block["reliability"] = ece["reliability"]
    unb = [m for m in metrics if is_unbounded(m)]
    block["robust"] = robust_stats(cells, methods, unb, comparisons, n_boot, seed, loto)
    block["verdict"], block["verdict_table"] = verdict(cells, block["paired"], block["robust"], scope, n_boot, seed,
                                                       loto)
    return block
