"""The population blocks with calibration metrics and verdict records, and the attribution variants:
the main block, ``ablations.attribution`` and one block per ``evaluate.ablations`` entry
(``pipeline.evaluation.statistics.engine.population_block``; ECE from ``pooled_calibration``)."""
from __future__ import annotations

import pandas as pd

from pipeline.evaluation.metrics.labels import (ATTRIBUTION, ATTRIBUTION_COMPARISONS, MODEL_BASED, WITH_UNCERTAINTY,
                                                comparisons, methods)
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.engine import population_block
from pipeline.evaluation.statistics.pooled_calibration import track_sums
from pipeline.infra.config.evaluation import cluster_of

ATTRIBUTION_KEY = "attribution"
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
    out["main"] = population_block(dtab[dtab["method"].isin(main)], main, metrics, comparisons(), ev.bootstrap, ev.seed,
                                   primary=prim, ece={"sums": sums}, cluster=cl)
    abl = {}
    att = [m for m in (WITH_UNCERTAINTY, MODEL_BASED, *ATTRIBUTION) if m in set(dtab["method"])]
    if all(m in att for m in ATTRIBUTION):
        b = population_block(dtab[dtab["method"].isin(att)], att, metrics, ATTRIBUTION_COMPARISONS, ev.bootstrap,
                             ev.seed, primary=prim, ece={"sums": sums}, per_target=False, cluster=cl)
        abl[ATTRIBUTION_KEY] = {"kind": "attribution", "methods": att,
                                "override": {"with_uncertainty_poses_only": "dropout samples replaced by their mean",
                                             "with_uncertainty_dropout_only": "no pose sampling (sigma = 0, N_x = 1)"},
                                **{k: b[k] for k in BLOCK_KEYS}}
    for a in ev.ablations:
        sub = table[(table["variant"] == a) & table["method"].isin(main)]
        if sub.empty:
            continue
        b = population_block(sub, main, metrics, comparisons(), ev.bootstrap, ev.seed, primary=prim,
                             ece={"sums": track_sums(cells, results, a, ev.ece_bins)}, per_target=False, cluster=cl)
        key, value = (t.strip() for t in a.split("=", 1))
        abl[a] = {"override": {key: value}, **{k: b[k] for k in (*BLOCK_KEYS, "reliability") if k in b}}
    out["ablations"] = abl
    return out
