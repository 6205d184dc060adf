"""The population evaluation's tables and summary, from the cells' reduced results (pure functions).

The evaluate stage keeps of each cell only its ``pipeline.evaluation.grid.cell_reduce.reduce_cell``
summary (``kept``). ``cell_table``: one row per (variant, target, track, setting, method) with the
cell's metrics (``pipeline.evaluation.metrics.spec``); ``population_summary``: the ``population`` object
of ``evaluate/summary.json`` (statistics from ``pipeline.evaluation.statistics.engine``).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.contrast import contrast_block
from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.grid.primary import declared_pair
from pipeline.evaluation.metrics.labels import comparisons, methods as method_keys
from pipeline.evaluation.metrics.spec import METRICS, check_primary, percentile  # noqa: F401 - check_primary: public here
from pipeline.evaluation.statistics.design import MIN_CLUSTERS
from pipeline.evaluation.statistics.engine import population_block
from pipeline.evaluation.statistics.resampler import LEVEL
from pipeline.infra.config.evaluation import cluster_of
from pipeline.method import registry as method_registry


def cell_table(kept: list[dict]) -> pd.DataFrame:
    """One row per (variant, target, track, setting, method) with the cell's metrics, from the
    cells' ``cell_reduce.reduce_cell`` summaries in grid order."""
    return pd.DataFrame([row for k in kept for row in k["rows"]])


STATISTICS = {
    "resampler": "one bootstrap whose top level is the design's independent unit (evaluate.statistics.cluster; "
                 "'cluster' and 'unit' below), its draws shared by every metric, method and paired difference of the "
                 "run",
    "interval": "percentile (2.5th and 97.5th percentiles of the resampled statistic)",
    "infinity": "infinite values are kept; an interval end that is infinite is unbounded (null in JSON); an "
                "undefined resampled statistic (inf - inf) gives no interval",
    "outcome": "better / worse when the 95 % interval of method - baseline excludes 0 on that side, else not "
               "distinguishable; withheld (no CI, no verdict) where a level the design varies over has fewer "
               f"than {MIN_CLUSTERS} units",
    "pooling": "per metric (spec): the mean over targets of the target means, or the median over targets for "
               "unbounded metrics (log10 MGR percentiles, NLL); ECE from the pooled posteriors",
    "multiplicity": "Holm over the primary family (With Uncertainty against each baseline on each primary metric), "
                    "familywise 95 %: step by step each open interval is widened to level 1 - 0.05/(open records); "
                    "records carry both verdicts (outcome, outcome_holm); the bottom line and scorecard read the "
                    "adjusted one",
}


# How the pooled values and their CIs are built, per clustering (evaluate.statistics.cluster).
_KEEP = " (per-target CIs: tracks; the pooled ECE and leave-one-target-out: targets, then tracks)."
UNIT = {
    "target": "Pooled values average tracks' means (over settings) within each target, then targets; 95 % CIs "
              "resample targets, then tracks within targets (per-target CIs: tracks).",
    "scan": "Pooled values average tracks' means (over settings) within each (scan, target), then pool the targets "
            "of each scan, then average scans; 95 % CIs resample scans, then the targets of each drawn scan, then "
            "their tracks in it" + _KEEP,
    "category": "Pooled values average tracks' means (over settings) within each target, pool the targets of each "
                "category, then average categories; 95 % CIs resample categories, then the targets of each drawn "
                "category, then their tracks" + _KEEP,
    "crossed": "Pooled values average tracks' means (over settings) within each target, then targets; 95 % CIs "
               "resample targets and scans independently (a two-way bootstrap: each (target, scan) cell's tracks "
               "weigh the product of the two multiplicities; tracks are not resampled within a cell)" + _KEEP,
}


def population_summary(cfg, table: pd.DataFrame, cells: list[P.Cell], results: list[dict],
                       tracks: list[P.TrackInfo], skipped: list[dict], domain_fit: dict | None = None) -> dict:
    """``summary.json``'s ``population`` object from the ``evaluate`` config section ``ev``, the
    cell table and the cells' reduced results (``reduce_cell``): pooled values, paired differences
    and verdicts (whole population, per setting, per ablation), difficulty, per-cell values and
    the tracks."""
    from pipeline.evaluation.grid import population_calibration as PC  # heavy: pandas

    ev = cfg.evaluate
    metrics = list(METRICS)
    methods = [m for m in method_keys() if m in set(table["method"])]
    settings = P.population_settings(ev)
    default = table[table["variant"] == DEFAULT]
    n_targets = default["target"].nunique()
    n_tracks = len(tracks)
    scope = f"{n_targets} targets x {n_tracks} tracks x {len(settings)} settings"
    cluster = cluster_of(ev)
    if cluster in ("scan", "crossed"):
        scope = f"{default['scan'].nunique()} scans, " + scope
    check_primary(ev.primary_metrics)
    blocks = PC.population_blocks(cfg, table, cells, results, scope, DEFAULT)
    block, ablations = blocks["main"], blocks["ablations"]
    main = default[default["method"].isin(methods)]
    by_setting = {}
    for s in settings:
        sub = main[main["setting"] == s.label]
        b = population_block(sub, methods, metrics, comparisons(), ev.bootstrap, ev.seed,
                             primary=tuple(ev.primary_metrics), per_target=False, loto=False,
                             cluster=cluster, exclude=declared_pair(ev, [s.label]))
        by_setting[s.label] = {k: b[k] for k in PC.BLOCK_KEYS}
    difficulty = [{"target": c.target, "track": c.track, "scan": c.scan, "single_view_first": r["difficulty"]}
                  for c, r in zip(cells, results) if r["difficulty"] is not None]
    spread = {}
    for m in methods:
        # a method without a single-view reading (FusionMethod.single_view is optional) has no entry
        v = np.array([d["single_view_first"][m] for d in difficulty if m in d["single_view_first"]])
        if not len(v):
            continue
        spread[m] = {"min": float(v.min()), "q25": float(percentile(v, 25)), "median": float(np.median(v)),
                     "q75": float(percentile(v, 75)), "max": float(v.max()), "mean": float(v.mean())}
    first = {c.target: c for c in cells if c.variant == DEFAULT}
    cell_rows = [{"target": t, "track": int(tr), "experiment": e, "setting": s,
                  "values": {r["method"]: {k: r[k] for k in metrics} for _, r in g.iterrows()}}
                 for (t, tr, e, s), g in default.groupby(["target", "track", "experiment", "setting"], sort=True)]
    return {
        "n_targets": int(n_targets), "n_tracks": int(n_tracks), "tracks_per_target": ev.tracks_per_target,
        "n_cells": int(len(main) // max(len(methods), 1)), "bootstrap": ev.bootstrap, "ci_level": LEVEL,
        "confident_threshold": ev.confident_threshold, "ece_bins": ev.ece_bins,
        "primary_metrics": list(ev.primary_metrics), "statistics": STATISTICS, "scope": scope,
        "likelihood": ev.test_domain_variance,
        "calibration_weighting": ("ECE and the reliability diagram pool every posterior of the population, "
                                  "weighted as the other pooled values: each target the same, each track of a "
                                  "target the same, each setting of a track the same, each realization (final "
                                  "step) or realization and step (all steps) of a setting the same"),
        "realizations": ev.randomized.realizations, "n_loc_samples": ev.randomized.n_loc_samples,
        "methods": methods, "metrics": metrics,
        "settings": [{"experiment": s.experiment, "setting": s.label, "sigma_m": s.sigma, "bias_m": list(s.bias),
                      "realizations": s.realizations, "n_loc_samples": s.n_x} for s in settings],
        "targets": sorted(first), "candidates": {t: list(c.classes) for t, c in sorted(first.items())},
        "components": {t: list(c.components) for t, c in sorted(first.items())},
        "unit": "a cell is one (target, track, setting); its metric is computed over its realizations. " + UNIT[cluster],
        "cluster": cluster,
        **block,
        "by_setting": by_setting,
        "by_category": blocks.get("by_category") or {},
        "difficulty": {"tracks": difficulty, "summary": spread,
                       "meaning": "share of a track's views whose single-view posterior at the true pose ranks "
                                  "the target first"},
        "cells": cell_rows,
        "tracks": [t.as_dict() for t in tracks],
        "ablations": ablations,
        "contrast": contrast_block(ev, table),   # data.real_imagery.contrast: instance vs category arm, else None
        "domain_fit": domain_fit or {},
        "skipped_targets": skipped,
    }


def method_blocks(cfg, cells: list[P.Cell], results: list[dict], population: dict) -> dict:
    """summary.json's block of each method that reports one beside its posterior
    (``FusionMethod.population_block``), from its extras in the default cells' ``reduce_cell``
    summaries ``results``; keyed by the method."""
    out = {}
    for m in method_registry.methods():
        pairs = [(c, r["extras"][m.key]) for c, r in zip(cells, results)
                 if c.variant == DEFAULT and m.key in r.get("extras", {})]
        block = m.population_block(cfg, pairs) if pairs else None
        if block is not None:
            if m.key in population:
                raise ValueError(f"method {m.key!r}: its summary block would replace the population's {m.key!r}")
            out[m.key] = block
    return out
