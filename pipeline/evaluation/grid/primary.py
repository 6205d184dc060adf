"""The one primary comparison declared before the run (``evaluate.primary``: a metric, a method
against a baseline, a localization setting) and the paired comparisons read on one setting only
(the paper's §5.5 test: ``pipeline.evaluation.grid.paper55``).

Each is one verdict record of the statistics engine (``population_block``), on the default
variant's cells of the named setting(s), with the run's clustering and draws, and outside any
multiplicity family (``primary=()``): the declared comparison is the only one, so it is read at
its own 95 %. Whatever interval the engine gives (its clustering, its calibration) flows through
unchanged. ``paired_table``: the per-track paired differences the power analysis
(``pipeline.evaluation.statistics.power``) estimates its variance components from.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.metrics.labels import comparison_key
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.engine import population_block
from pipeline.infra.config.evaluation import cluster_of
from pipeline.infra.config.fields import ConfigError
from pipeline.method.registry import keys

ATTRIBUTION_VARIANTS = ("with_uncertainty_poses_only", "with_uncertainty_dropout_only")


def check_declared(ev) -> None:
    """``evaluate.primary`` names a metric of the spec and two registered methods the run evaluates
    (a ConfigError naming the key otherwise): checked before any cell runs."""

    pm = ev.primary
    if pm.metric not in METRICS:
        raise ConfigError(f"config 'evaluate.primary.metric' = {pm.metric!r}: not a metric of the spec "
                          f"(known: {', '.join(METRICS)})")
    known = keys(attribution=True)
    for m in pm.methods:
        if m not in known:
            raise ConfigError(f"config 'evaluate.primary.methods' names {m!r}: not a registered method "
                              f"(known: {', '.join(known)})")
        if m in ATTRIBUTION_VARIANTS and not ev.attribution:
            raise ConfigError(f"config 'evaluate.primary.methods' names {m!r}, which runs only with "
                              "'evaluate.attribution' = true")


def setting_labels(ev, setting: str) -> list[str]:
    """The population settings' labels a declared setting covers ('all': every one; an experiment:
    its settings); [] when the run has none of them."""
    return [s.label for s in P.population_settings(ev) if setting == "all" or s.experiment == setting]


def setting_cells(table: pd.DataFrame, labels: list[str], methods: tuple[str, ...]) -> pd.DataFrame:
    d = table[(table["variant"] == DEFAULT) & table["method"].isin(methods)]
    return d[d["setting"].isin(labels)]


def comparison_record(ev, table: pd.DataFrame, method: str, baseline: str, metric: str, setting: str) -> dict:
    """{"setting", "settings", "record"} of method - baseline on ``metric`` in ``setting``; "record"
    None with a "missing" reason where the run has no such cells."""
    labels = setting_labels(ev, setting)
    out = {"comparison": comparison_key(method, baseline), "method": method, "baseline": baseline,
           "metric": metric, "setting": setting, "settings": labels, "record": None}
    cells = setting_cells(table, labels, (method, baseline))
    present = set(cells["method"]) if len(cells) else set()
    if not labels or present != {method, baseline}:
        out["missing"] = ("the run has no " + (f"'{setting}' setting" if not labels else
                                               " or ".join(sorted({method, baseline} - present)) + " cells"))
        return out
    b = population_block(cells, [method, baseline], [metric], ((method, baseline),), ev.bootstrap, ev.seed,
                         primary=(), per_target=False, loto=False, cluster=cluster_of(ev))
    recs = [r for r in b["records"] if r["comparison"] == out["comparison"] and r["metric"] == metric]
    out["record"] = recs[0] if recs else None
    return out


def declared_pair(ev, labels) -> set[tuple[str, str]]:
    """{(comparison, metric)} of the declared comparison where a block's settings (``labels``) are
    exactly the declared setting's: that block's record of it is the declared test itself, so it
    leaves the block's exploratory Holm family (``multiplicity.holm``'s ``exclude``); empty otherwise
    (another setting's record is another statistic and stays in its family)."""
    pm = ev.primary
    declared = setting_labels(ev, pm.setting)
    if not declared or sorted(declared) != sorted(labels):
        return set()
    return {(comparison_key(pm.methods[0], pm.methods[1]), pm.metric)}


def declared_block(ev, table: pd.DataFrame) -> dict:
    """summary.json's ``population.primary``: the declared comparison's record, not adjusted."""
    pm = ev.primary
    out = comparison_record(ev, table, pm.methods[0], pm.methods[1], pm.metric, pm.setting)
    out.update(declared="evaluate.primary", adjusted=False,
               adjustment="none: the one comparison declared before the run, read at its own 95 %")
    return out


def paired_table(table: pd.DataFrame, method: str, baseline: str, metric: str, labels: list[str]) -> pd.DataFrame:
    """One row per (target, scan, track): the mean over the named settings of method - baseline on
    ``metric`` (columns target, scan, track, d); rows with an undefined difference are dropped."""
    cells = setting_cells(table, labels, (method, baseline))
    if cells.empty:
        return pd.DataFrame({"target": [], "scan": [], "track": [], "d": []})
    if "scan" not in cells:
        cells = cells.assign(scan="")
    keys = ["target", "scan", "track", "setting"]
    a = cells[cells["method"] == method].set_index(keys)[metric]
    b = cells[cells["method"] == baseline].set_index(keys)[metric]
    d = (a - b).replace([np.inf, -np.inf], np.nan).dropna()
    return d.groupby(level=["target", "scan", "track"]).mean().rename("d").reset_index()
