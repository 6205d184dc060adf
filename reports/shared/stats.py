"""Confidence intervals of the single-track experiments: over realizations of one track.

The population CIs (over tracks and targets) come from ``summary.json``; the single-track
experiments (the σ sweep, the randomized detail of the first track) only vary the localization
noise, so their CIs resample realizations, with the statistics engine's one resampler and
interval rule (``pipeline.evaluation.statistics.engine.over_realizations``) and the run's metric
parameters (``metric_params``: the confident threshold the population used).
"""
from __future__ import annotations

from collections.abc import Mapping

import pandas as pd

from pipeline.evaluation.metrics.labels import ordered_methods
from pipeline.evaluation.metrics.spec import Params, matrices
from pipeline.evaluation.statistics.engine import over_realizations
from reports.shared.numbers import Estimate
from pipeline.infra.config.evaluation import CONFIDENT_THRESHOLD, ECE_BINS

BOOTSTRAP = 1000


def metric_params(summary: Mapping, config: Mapping | None = None) -> Params:
    """The run's ``Params``: from a summary block that records them (``population`` or the
    simulate summary's ``claim_params``), else the resolved config's evaluate section, else the
    config's defaults."""

    src = dict((config or {}).get("evaluate") or {})
    src.update({k: v for k, v in (summary.get("claim_params") or {}).items() if k == "confident_threshold"})
    src.update({k: v for k, v in summary.items() if k in ("confident_threshold", "ece_bins") and v is not None})
    return Params(float(src.get("confident_threshold", CONFIDENT_THRESHOLD)), int(src.get("ece_bins", ECE_BINS)))


def bootstrap_track(mats: dict, params: Params, n_boot: int = BOOTSTRAP, seed: int = 0) -> dict[str, Estimate]:
    """Each metric of ``pipeline.evaluation.metrics.spec.METRICS`` with its CI over realizations
    (rows of the (R, K) matrices, see ``metrics.matrices``)."""
    return {k: Estimate.of(e) for k, e in over_realizations(mats, params, n_boot, seed).items()}


def track_summary(df: pd.DataFrame, params: Params, *, n_boot: int = BOOTSTRAP, seed: int = 0,
                  by: str = "setting") -> dict:
    """{setting: {"sigma_m", "n_realizations", "methods": {method: {metric: Estimate}}}}, groups of
    ``by`` in order of first appearance; the seed is the same for every cell so reruns agree."""
    out: dict = {}
    for setting in dict.fromkeys(df[by]):
        g = df[df[by] == setting]
        sigma = float(g["sigma_m"].iloc[0]) if "sigma_m" in g else float("nan")
        cell = {"sigma_m": sigma, "n_realizations": int(g["realization"].nunique()), "methods": {}}
        for m in ordered_methods(g["method"].unique()):
            cell["methods"][m] = bootstrap_track(matrices(g[g["method"] == m]), params, n_boot, seed)
        out[setting] = cell
    return out
