"""Dirichlet (Tchuiev & Indelman 2018): one Dirichlet per class over the classifier's whole
probability vector, the dropout samples fused as a posterior cloud
(``pipeline.method.dirichlet_fusion``). View-independent; not in the simulation, whose measurements
are GP scores, not probability vectors. Its class models are its own (``DirichletProvider``,
``pipeline.method.provider``): fitted by the models stage into ``models/dirichlet/`` with the
settings ``models.dirichlet.*``, loaded by evaluate with ``evaluate.dirichlet.n_ss``."""
from __future__ import annotations

import numpy as np

from pipeline.infra.config import to_dict
from pipeline.method import dirichlet as D
from pipeline.method import dirichlet_fusion as DF
from pipeline.method.names import DIRICHLET
from pipeline.method.method_base import FusionMethod, TrackInput, register
from pipeline.method.provider import ModelProvider, register_provider


@register_provider
class DirichletProvider(ModelProvider):
    key = DIRICHLET
    label = "Dirichlet class models"

    def fit(self, views, cfg):
        """Per class, Dir(γ; θ_c) on the whole score vectors of its training ring
        (``models.dirichlet.passes``); with ``models.dirichlet.entries = n``, also per candidate set
        each class's Dirichlet on the set's first n chosen components plus the rest mass."""
        dcfg = cfg.models.dirichlet
        vectors = D.class_vectors(views, dcfg)
        models, diags = D.fit_class_dirichlets(vectors, floor=dcfg.floor, tol=dcfg.tol, max_iter=dcfg.max_iter,
                                               accelerate=dcfg.accelerate)
        if dcfg.entries and views.plan:
            models.sets, set_diags = D.reduced_sets(vectors, views.plan, dcfg, views.scores.shape[1])
            diags = diags + set_diags
        extra = {"fit": {"method": "Minka fixed point from the moment estimate"
                                   + (", SQUAREM-accelerated" if dcfg.accelerate else ""), "camera": views.camera,
                         **to_dict(dcfg)},
                 "diagnostics": diags, "fits_not_converged": sum(1 for d in diags if not d["converged"])}
        return models, extra

    def save(self, models, folder, extra):
        models.save(folder, extra=extra)

    def load(self, folder, cfg):
        models = D.DirichletModels.load(folder)
        models.n_ss = cfg.evaluate.dirichlet.n_ss
        return models

    def digest(self, models) -> str:
        return models.fingerprint()

    def record(self, models, extra) -> dict:
        return {"not_converged": extra["fits_not_converged"]}

    def summary(self, models, extra, cfg) -> str:
        return (f"{len(models.classes)} Dirichlet class models ({cfg.models.dirichlet.passes} passes, "
                f"{extra['fits_not_converged']} not converged)")

    def for_cell(self, models, target, classes, dim):
        dm = models.for_set(target, classes)   # models.dirichlet.entries: the set's reduced models
        if dim != dm.dim:
            raise ValueError(f"{dim} scores per crop, the Dirichlet models {dm.dim}")
        return dm


@register
class Dirichlet(FusionMethod):
    key = DIRICHLET
    label = "Dirichlet (Tchuiev & Indelman)"
    short = "Dirichlet"
    color = "#CC79A7"
    note = ("one Dirichlet distribution per class over the classifier's whole probability vector, fused over the "
            "dropout samples; ignores the viewpoint and the poses")
    needs = frozenset({DIRICHLET, "probs"})
    uses_poses = False

    def fuse_with_extras(self, t: TrackInput) -> tuple[np.ndarray, dict]:
        """log E[λ] per step (K, C), and the cloud's std of λ (K, C) as ``std``."""
        dm = t.models[DIRICHLET]
        log_mean, std = DF.fuse_dirichlet(dm, t.probs, n_ss=dm.n_ss, rng=t.rng)
        return log_mean, {"std": std}

    def fuse(self, t: TrackInput) -> np.ndarray:
        return self.fuse_with_extras(t)[0]

    def single_view(self, t: TrackInput) -> np.ndarray:
        return DF.single_view(t.models[DIRICHLET], t.probs)

    def population_block(self, cfg, pairs) -> dict | None:
        """What the posterior cloud says besides its mean: the spread (std of λ) of the truth's
        probability at the final step over the default cells, and the first cell's per-step E[λ]
        and std (``pairs``: (cell, its kept extras) of the default variant's cells)."""
        if not pairs:
            return None
        final = np.array([x["std"][-1, c.truth] for c, x in pairs])
        c0, x0 = pairs[0]
        return {"n_ss": cfg.evaluate.dirichlet.n_ss, "poses": "ignored: the same posterior for every realization",
                "truth_std_final": {"median": float(np.median(final)), "q25": float(np.percentile(final, 25)),
                                    "q75": float(np.percentile(final, 75)), "max": float(final.max()),
                                    "n_cells": int(len(final))},
                "first_track": {"target": c0.target, "track": c0.track, "classes": list(c0.classes),
                                "mean": x0["posterior0"].tolist(), "std": x0["std"].tolist()}}
