"""The population blocks with calibration metrics and verdict records, and the attribution variants:
the main block, ``ablations.attribution``, the instance term's attribution (``INSTANCE_KEY``,
``INSTANCE_COMPARISONS``), one block per ``evaluate.ablations`` entry, and on a
category benchmark one block per category (``by_category``)
(``pipeline.evaluation.statistics.engine.population_block``; ECE from ``pooled_calibration``)."""
from __future__ import annotations

import pandas as pd

from pipeline.evaluation.metrics.labels import (ATTRIBUTION, ATTRIBUTION_COMPARISONS, INSTANCE_COMPARISONS, MB_INSTANCE,
                                                MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE, comparisons,
                                                instance_goal_comparisons, methods)
from pipeline.method.names import INSTANCE_BLOCK
from pipeline.evaluation.grid.population import population_settings
from pipeline.evaluation.grid.primary import declared_pair
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.engine import population_block
from pipeline.evaluation.statistics.pooled_calibration import track_sums
from pipeline.infra.config.evaluation import cluster_of
from pipeline.scene.folds import category_of

ATTRIBUTION_KEY = "attribution"
INSTANCE_KEY = INSTANCE_BLOCK
# The per-category breakdown's metrics: the goal of the instance term is stated in these.
CATEGORY_METRICS = ("correct_final", "confident_error_final")
BLOCK_KEYS = ("pooled", "paired", "records")


def population_blocks(cfg, table: pd.DataFrame, cells, results, scope: str, default: str) -> dict:
    """Main block (calibration metrics and records), attribution block and ablation blocks; every
    block on the same shared draws (same targets and tracks, same seed)."""
    ev = cfg.evaluate
    metrics = list(METRICS)
    main = [m for m in methods() if m in set(table["method"])]
    prim = tuple(ev.primary_metrics)
    cl = cluster_of(ev)
    out = {}
    sums = track_sums(cells, results, default, ev.ece_bins)
    dtab = table[table["variant"] == default]
    every = [s.label for s in population_settings(ev)]
    out["main"] = population_block(dtab[dtab["method"].isin(main)], main, metrics, comparisons(), ev.bootstrap, ev.seed,
                                   primary=prim, ece={"sums": sums}, cluster=cl, exclude=declared_pair(ev, every))
    abl = {}
    att = [m for m in (WITH_UNCERTAINTY, MODEL_BASED, *ATTRIBUTION) if m in set(dtab["method"])]
    if all(m in att for m in ATTRIBUTION):
        b = population_block(dtab[dtab["method"].isin(att)], att, metrics, ATTRIBUTION_COMPARISONS, ev.bootstrap,
                             ev.seed, primary=prim, ece={"sums": sums}, per_target=False, cluster=cl)
        abl[ATTRIBUTION_KEY] = {"kind": "attribution", "methods": att,
                                "override": {"with_uncertainty_poses_only": "dropout samples replaced by their mean",
                                             "with_uncertainty_dropout_only": "no pose sampling (sigma = 0, N_x = 1)"},
                                **{k: b[k] for k in BLOCK_KEYS}}
    if any(a in main and b in main for a, b in INSTANCE_COMPARISONS):
        # exploratory records (outside the primary family: no Holm adjustment), on the main block's draws
        pairs = INSTANCE_COMPARISONS + instance_goal_comparisons(main)
        b = population_block(dtab[dtab["method"].isin(main)], main, metrics, pairs, ev.bootstrap,
                             ev.seed, primary=prim, ece={"sums": sums}, per_target=False, cluster=cl)
        abl[INSTANCE_KEY] = {"kind": "attribution", "methods": main,
                             "override": {WU_INSTANCE: "class models with an instance term",
                                          MB_INSTANCE: "class models with an instance term"},
                             **{k: b[k] for k in BLOCK_KEYS}}
    for a in ev.ablations:
        sub = table[(table["variant"] == a) & table["method"].isin(main)]
        if sub.empty:
            continue
        # a method whose models follow the default bank only (ModelProvider.default_only: the instance
        # term) skips in a variant with a bank of its own: pair only the methods the variant ran
        ran = [m for m in main if m in set(sub["method"])]
        b = population_block(sub, ran, metrics, comparisons(), ev.bootstrap, ev.seed, primary=prim,
                             ece={"sums": track_sums(cells, results, a, ev.ece_bins)}, per_target=False, cluster=cl)
        key, value = (t.strip() for t in a.split("=", 1))
        abl[a] = {"override": {key: value}, **{k: b[k] for k in (*BLOCK_KEYS, "reliability") if k in b}}
    out["ablations"] = abl
    out["by_category"] = category_blocks(dtab[dtab["method"].isin(main)], main, ev.bootstrap, ev.seed)
    return out


def categories(targets) -> dict[str, list[str]] | None:
    """{category: its targets} when every target is a category class ``<category>__f<k>`` and
    there are two categories or more; None otherwise (an instance-level benchmark)."""
    out: dict[str, list[str]] = {}
    for t in sorted(set(map(str, targets))):
        try:
            out.setdefault(category_of(t), []).append(t)
        except ValueError:
            return None
    return out if len(out) > 1 else None


def category_blocks(table: pd.DataFrame, methods_: list[str], n_boot: int, seed) -> dict:
    """Per category: every method's correct ratio and confident-error rate and the paired
    differences (the primary comparisons, the instance term's and its goal's), 95 % CIs over that category's
    targets, then their tracks. Exploratory: no verdict records, no multiplicity adjustment."""
    cats = categories(table["target"]) if len(table) else None
    if not cats:
        return {}
    pairs = tuple(dict.fromkeys((*comparisons(), *INSTANCE_COMPARISONS, *instance_goal_comparisons(methods_))))
    out = {}
    for cat, targets in cats.items():
        b = population_block(table[table["target"].isin(targets)], methods_, list(CATEGORY_METRICS), pairs, n_boot,
                             seed, per_target=False, loto=False, cluster="target")
        out[cat] = {"targets": targets, "pooled": b["pooled"], "paired": b["paired"]}
    return out
