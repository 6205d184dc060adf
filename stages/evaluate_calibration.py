"""The evaluate stage's calibration parts: test-domain fit, the cross-fitted test-domain variance of
the calibrated likelihood, and the population blocks with calibration metrics, robust statistics
and the attribution variants. The statistics are pure functions in ``pipeline.evaluation``
(``domain_fit``, ``test_domain_variance``, ``pooled_calibration``, ``verdicts``); this module wires
them to the stage's tables.
"""
from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd

from pipeline.evaluation import domain_fit as D
from pipeline.evaluation import population as P
from pipeline.evaluation import test_domain_variance as V
from pipeline.evaluation.labels import (ATTRIBUTION, ATTRIBUTION_COMPARISONS, METHODS, MODEL_BASED,
                                        WITH_UNCERTAINTY)
from pipeline.evaluation.pooled_calibration import pooled_ece, track_sums
from pipeline.evaluation.verdicts import full_block
from pipeline.infra.config import test_domain_mode

log = logging.getLogger("viewfuse.evaluate")

ATTRIBUTION_KEY = "attribution"


def instance_poses(cfg, avd: pd.DataFrame, truth: dict | None, intr: dict, classes) -> tuple[dict, str]:
    """{(scan, instance): (object xy, yaw rad)} for every modelled instance the AVD features show,
    from the synthetic sidecar (position and yaw) or, with ``yaw_source = 'config'``, the located
    object and the configured yaw (configured targets only). Returns the poses and their source."""
    ev = cfg.evaluate
    out = {}
    det = avd[(avd["pass"] == -1) & (avd["difficulty"] <= ev.max_difficulty) & avd["instance"].isin(classes)]
    for (scan, inst), d in det.groupby(["scan", "instance"], sort=True):
        entry = P.truth_entry(truth, scan, inst)
        if ev.yaw_source == "truth" and entry is not None and "position" in entry:
            out[(scan, inst)] = (np.asarray(entry["position"], float), math.radians(float(entry["yaw_deg"])))
        elif ev.yaw_source == "config" and not isinstance(ev.targets, str) and inst in ev.targets:
            d = d.drop_duplicates("image")
            if len(d) >= 2:
                yaw = P.yaw_for(inst, scan, truth, "config", ev.yaw_deg, ev.targets, ev.yaws_deg)
                out[(scan, inst)] = (P.locate(d, *intr[scan]), yaw)
    return out, ("synthetic sidecar (truth.json)" if ev.yaw_source == "truth" else "located object, configured yaw")


class TestDomain:
    """Residuals of the labelled crops, the cross-fitted δ² per fold and the domain-fit summary."""

    def __init__(self, cfg, avd, scores, bank, truth, intr, targets, scans):
        self.poses, self.pose_source = instance_poses(cfg, avd, truth, intr, bank.classes)
        self.table = D.crop_residuals(avd, scores, bank, self.poses, cfg.evaluate.max_difficulty,
                                      cfg.evaluate.variance_floor)
        self.components = list(bank.components)
        keys = scans if len(scans) >= 2 else targets
        by = "scan" if len(scans) >= 2 else "instance"
        if self.table.empty:
            self.by, self.est, self.used = by, {str(k): {int(f): 0.0 for f in self.components} for k in keys}, {}
        else:
            self.by, self.est, self.used = V.cross_fit(self.table, self.components, by=by, keys=keys)

    def cell_variance(self, scan: str, target: str, components) -> tuple[float, ...]:
        est = self.est.get(str(V.cell_fold(self.by, scan, target)), {})
        return tuple(float(est.get(int(c), 0.0)) for c in components)

    def summary(self) -> dict:
        t = self.table
        if t.empty:
            return {"n_crops": 0, "note": "no labelled AVD crop of a modelled class with a known pose"}
        delta = V.row_variances(t, self.by, self.est)
        z = {kind: D.standardized(t, kind, delta if kind == "gp_calibrated" else None)
             for kind in ("gp", "gp_plus_dropout", "gp_calibrated")}
        out = D.summarize(t, z)
        n_crops = int(t.groupby(["scan", "instance", "image"]).ngroups)
        return {**out, "n_crops": n_crops, "pose_source": self.pose_source,
                "observed": "mean of the crop's MC-dropout scores; z = (observed - GP mean) / sqrt(variance)",
                "kinds": {"gp": "GP predictive variance (sigma_n^2 included): what Model Based uses",
                          "gp_plus_dropout": "plus the view's dropout variance: what With Uncertainty adds",
                          "gp_calibrated": "plus the cross-fitted test-domain variance (each crop's own fold)"},
                "test_domain_variance": {
                    "unit": "one additive variance per score component, shared by every class",
                    "folds_by": self.by, "per_fold": {k: {str(f): v for f, v in e.items()} for k, e in self.est.items()},
                    "rows_used": {k: {str(f): v for f, v in e.items()} for k, e in self.used.items()},
                    "rule": ("cells of scan s use the estimate from the other scans' crops" if self.by == "scan" else
                             "cells of target t use the estimate from the other instances' crops")}}

    def ring_overlay(self, scan: str, classes, components) -> dict[str, np.ndarray]:
        """Observed mean scores of each class's crops in ``scan`` on the ring: theta (C, n) and y (C, F, n)."""
        per = []
        for c in classes:
            sub = self.table[(self.table["scan"] == scan) & (self.table["instance"] == c)]
            per.append(sub)
        n = max([len(s[s["component"] == components[0]]) for s in per] + [1])
        th = np.full((len(classes), n), np.nan)
        y = np.full((len(classes), len(components), n), np.nan)
        for ci, sub in enumerate(per):
            for fi, f in enumerate(components):
                s = sub[sub["component"] == f]
                y[ci, fi, : len(s)] = s["obs"].to_numpy(float)
                if fi == 0:
                    th[ci, : len(s)] = np.arctan2(s["x1"].to_numpy(float), s["x0"].to_numpy(float))
        return {"obs_theta": th, "obs_y": y}


def test_variances(cells: list[P.Cell], domain: TestDomain, cfg) -> list[P.Cell]:
    """Cells with their δ² where their variant's likelihood is the calibrated one."""
    import dataclasses

    out = []
    for c in cells:
        mode = test_domain_mode(cfg, None if c.variant == "default" else c.variant)
        if mode == "cross_fit":
            c = dataclasses.replace(c, test_variance=domain.cell_variance(c.scan, c.target, c.components))
        out.append(c)
    return out


def population_blocks(cfg, table: pd.DataFrame, cells, results, scope: str, default: str) -> dict:
    """Main block (calibration metrics and robust verdict), attribution block and ablation blocks."""
    from pipeline.evaluation.labels import COMPARISONS, METRICS

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
