"""The population blocks with calibration metrics, robust verdicts and the attribution variants:
the main block, ``ablations.attribution`` and one block per ``evaluate.ablations`` entry
(``pipeline.evaluation.statistics.verdicts.full_block``; ECE from ``pooled_calibration``)."""
from __future__ import annotations

import pandas as pd

from pipeline.evaluation.metrics.labels import (ATTRIBUTION, ATTRIBUTION_COMPARISONS, COMPARISONS, METHODS, MODEL_BASED,
                                        WITH_UNCERTAINTY)
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.pooled_calibration import pooled_ece, track_sums
from pipeline.evaluation.statistics.verdicts import full_block

ATTRIBUTION_KEY = "attribution"


def population_blocks(cfg, table: pd.DataFrame, cells, results, scope: str, default: str) -> dict:
    """Main block (calibration metrics and robust verdict), attribution block and ablation blocks."""
    ev = cfg.evaluate
    metrics = list(METRICS)
    main = [m for m in METHODS if m in set(table["method"])]
    out = {}
    sums = track_sums(cells, results, default)
    dtab = table[table["variant"] == default]
    out["main"] = full_block(dtab[dtab["method"].isin(main)], main, metrics, COMPARISONS, ev.bootstrap, ev.seed,
                             scope, ece=pooled_ece(sums, main, COMPARISONS, ev.bootstrap, ev.seed))
    abl = {}
    att = [m for m in (WITH_UNCERTAINTY, MODEL_BASED, *ATTRIBUTION) if m in set(dtab["method"])]
    if all(m in att for m in ATTRIBUTION):
        b = full_block(dtab[dtab["method"].isin(att)], att, metrics, ATTRIBUTION_COMPARISONS, ev.bootstrap, ev.seed,
                       scope, ece=pooled_ece(sums, att, ATTRIBUTION_COMPARISONS, ev.bootstrap, ev.seed, False),
                       per_target=False)
        abl[ATTRIBUTION_KEY] = {"kind": "attribution", "methods": att,
                                "override": {"with_uncertainty_poses_only": "dropout samples replaced by their mean",
                                             "with_uncertainty_dropout_only": "no pose sampling (sigma = 0, N_x = 1)"},
                                **{k: b[k] for k in ("pooled", "paired", "robust", "verdict", "verdict_table")}}
    for a in ev.ablations:
        sub = table[(table["variant"] == a) & table["method"].isin(main)]
        if sub.empty:
            continue
        b = full_block(sub, main, metrics, COMPARISONS, ev.bootstrap, ev.seed, scope,
                       ece=pooled_ece(track_sums(cells, results, a), main, COMPARISONS, ev.bootstrap, ev.seed),
                       per_target=False)
        key, value = (t.strip() for t in a.split("=", 1))
        abl[a] = {"override": {key: value},
                  **{k: b[k] for k in ("pooled", "paired", "robust", "verdict", "verdict_table", "reliability")
                     if k in b}}
    out["ablations"] = abl
    return out
