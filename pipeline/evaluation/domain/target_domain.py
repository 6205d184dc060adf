"""The evaluate stage's test-domain parts: the labelled crops' residuals, the cross-fitted
test-domain variance of the calibrated likelihood and the domain-fit summary. The statistics are
pure functions beside it (``domain.fit``, ``domain.variance``); the
population blocks are in ``pipeline.evaluation.grid.population_calibration``.
"""
from __future__ import annotations

import logging
import math

import numpy as np
import pandas as pd

from pipeline.evaluation.domain import fit as D
from pipeline.evaluation.domain.coverage import coverage_cis
from pipeline.evaluation.domain import source as U
from pipeline.evaluation.domain import tails
from pipeline.evaluation.grid import population as P
from pipeline.evaluation.domain import variance as V
from pipeline.infra.config import domain_variance_mode, is_model_ablation
from pipeline.infra.config.evaluation import cluster_of
from pipeline.method.score_space import of_models
from pipeline.scoring.classifiers import classifier

log = logging.getLogger("viewfuse.evaluate")

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
                try:
                    out[(scan, inst)] = (P.locate(d, *intr[scan], ev.max_ray_residual_m).xy, yaw)
                except P.InconsistentRays as e:  # no pose, so none of its crops enters the test domain
                    log.warning("test domain: %s in %s left out: %s", inst, scan, e)
    return out, ("synthetic sidecar (truth.json)" if ev.yaw_source == "truth" else "located object, configured yaw")


class TargetDomain:
    """Residuals of the labelled crops, the cross-fitted δ² per fold and the domain-fit summary."""

    def __init__(self, cfg, avd, scores, bank, truth, intr, targets, scans):
        self.poses, self.pose_source = instance_poses(cfg, avd, truth, intr, bank.classes)
        self.score_space = of_models(bank)[0]
        self.table = D.crop_residuals(avd, scores, bank, self.poses, cfg.evaluate.max_difficulty,
                                      cfg.evaluate.variance_floor)
        self.components = list(bank.components)
        self.n_boot, self.seed = int(cfg.evaluate.bootstrap), int(cfg.evaluate.seed)
        self.cluster = cluster_of(cfg.evaluate)   # the units the pooled coverage's CI resamples
        self.sources = mc_sources(cfg)
        keys = scans if len(scans) >= 2 else targets
        by = "scan" if len(scans) >= 2 else "instance"
        if self.table.empty:
            self.by, self.est, self.used = by, {str(k): {int(f): 0.0 for f in self.components} for k in keys}, {}
            self.tails: dict[str, dict[str, float]] = {}
        else:
            self.by, self.est, self.used = V.cross_fit(self.table, self.components, by=by, keys=keys)
            self.tails = tails.cross_fit_df(self.table, self._z(("gp", "gp_plus_dropout")), self.by, keys)

    def _z(self, kinds, delta=None) -> dict:
        return {kind: D.standardized(self.table, kind, delta if kind == "gp_calibrated" else None) for kind in kinds}

    def cell_tail(self, scan: str, target: str) -> dict[str, float] | None:
        """{heavy-tailed method key: ν} of the cell's fold (``domain.tails``), or None."""
        return self.tails.get(str(V.cell_fold(self.by, scan, target))) or None

    def cell_variance(self, scan: str, target: str, components) -> tuple[float, ...]:
        est = self.est.get(str(V.cell_fold(self.by, scan, target)), {})
        return tuple(float(est.get(int(c), 0.0)) for c in components)

    def summary(self, source: bool = True) -> dict:
        """The domain fit; ``source`` False leaves out the uncertainty-source bootstrap (an ablation bank's)."""
        t = self.table
        if t.empty:
            return {"n_crops": 0, "note": "no labelled AVD crop of a modelled class with a known pose"}
        delta = V.row_variances(t, self.by, self.est)
        z = self._z(("gp", "gp_plus_dropout", "gp_calibrated"), delta)
        z.update(tails.t_kinds(t, z, self.by, self.tails))   # the Student-t likelihood, read on the Gaussian scale
        out = D.summarize(t, z)
        for kind, ci in coverage_cis(t, z, self.cluster, self.n_boot, self.seed).items():
            out[kind]["overall"].update(ci)   # beside the share: its CI over the run's units
        n_crops = int(t.groupby(["scan", "instance", "image"]).ngroups)
        return {**out, "n_crops": n_crops, "uncertainty_source": self.source_summary() if source else {}, "pose_source": self.pose_source,
                "score_space": self.score_space,
                "observed": "mean of the crop's MC-dropout scores; z = (observed - GP mean) / sqrt(variance)",
                "kinds": {"gp": "GP predictive variance (sigma_n^2 included): what Model Based uses",
                          "gp_plus_dropout": "plus the view's dropout variance: what With Uncertainty adds",
                          "gp_calibrated": "plus the cross-fitted test-domain variance (each crop's own fold)",
                          "gp_t": "GP predictive as a Student-t, nu of the crop's own fold (Phi^-1 of its t PIT)",
                          "gp_plus_dropout_t": "plus the dropout variance as a Student-t, nu of the crop's own fold"},
                "tail_df": {"per_fold": self.tails, "folds_by": self.by,
                            "rule": "ML nu of a unit-scale t on the other folds' standardized residuals"},
                "test_domain_variance": {
                    "unit": "one additive variance per score component, shared by every class",
                    "folds_by": self.by, "per_fold": {k: {str(f): v for f, v in e.items()} for k, e in self.est.items()},
                    "rows_used": {k: {str(f): v for f, v in e.items()} for k, e in self.used.items()},
                    "rule": ("cells of scan s use the estimate from the other scans' crops" if self.by == "scan" else
                             "cells of target t use the estimate from the other instances' crops")}}

    def source_summary(self) -> dict:
        """How well the MC spread ranks the crops' distance from their class model (``domain.source``),
        with the sources the MC samples came from."""
        est = U.source_summary(U.per_crop(self.table), self.n_boot, self.seed)
        return {**est, "reading": U.reading(est), **self.sources}

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


KINDS = ("gp", "gp_plus_dropout", "gp_calibrated", "gp_t", "gp_plus_dropout_t")


def bank_fits(cfg, avd, scores, banks: dict, truth, intr, targets, scans, fit_only: dict | None = None) -> dict:
    """{ablation: the domain fit's pooled rows} for every ``models.*`` ablation's own model bank (a
    score space, a component rule ...) and every fit-only bank (``fit_only``: {name: a function
    that loads it}, the ``evaluate.fit_spaces`` banks no cell runs on; each is loaded, fitted and
    dropped in turn, so that at most one is held): the same crops and the same code path as the
    main bank's summary, so that the report shows each bank's 95 % coverage per likelihood. Only
    each kind's ``overall`` is kept (the per-class tables are the main bank's); a fit-only bank's
    entry says so (``fit_only``)."""
    todo = [(a, banks[a], False) for a in cfg.evaluate.ablations if is_model_ablation(a) and a in banks]
    todo += [(a, load, True) for a, load in (fit_only or {}).items()]
    out = {}
    for a, bank, only in todo:
        dom = TargetDomain(cfg, avd, scores, bank() if only else bank, truth, intr, targets, scans)
        s = dom.summary(source=False)
        out[a] = {"n_crops": s["n_crops"], "score_space": dom.score_space, "pose_source": dom.pose_source,
                  **({"fit_only": True} if only else {}), **{k: {"overall": s[k]["overall"]} for k in KINDS if k in s}}
    return out


def mc_sources(cfg) -> dict:
    """What produced the MC samples: head dropout always; drop-connect only where the run scored
    with it (then the spread is the two sources' joint one: they are not scored apart)."""

    c = cfg.classifier
    entry = classifier(c.arch)
    dc = float(entry.drop_connect(c))
    return {"source": f"MC dropout (p = {entry.head_dropout(c):g})" + (f" and drop-connect (rate {dc:g})" if dc else ""),
            "drop_connect": (f"scored together with the dropout (rate {dc:g}): the numbers are of their joint spread; "
                             "drop-connect alone was not scored") if dc else
                            "not scored in this run (classifier drop-connect off): no second source to measure"}


def target_variances(cells: list[P.Cell], domain: TargetDomain, cfg) -> list[P.Cell]:
    """Cells with their δ² where their variant's likelihood is the calibrated one, and their fold's
    Student-t degrees of freedom with ``evaluate.likelihood_tail = "student_t"``."""
    import dataclasses

    out = []
    for c in cells:
        mode = domain_variance_mode(cfg, None if c.variant == "default" else c.variant)
        if mode == "cross_fit":
            c = dataclasses.replace(c, test_variance=domain.cell_variance(c.scan, c.target, c.components))
        if cfg.evaluate.likelihood_tail == "student_t":
            c = dataclasses.replace(c, tail_df=domain.cell_tail(c.scan, c.target))
        out.append(c)
    return out
