"""Dirichlet (Tchuiev & Indelman 2018): one Dirichlet per class over the classifier's whole
probability vector, the dropout samples fused as a posterior cloud
(``pipeline.method.dirichlet_fusion``). View-independent; not in the simulation, whose measurements
are GP scores, not probability vectors. Its class models are its own (``DirichletProvider``,
``pipeline.method.provider``): fitted by the models stage into ``models/dirichlet/`` with the
settings ``models.dirichlet.*``, loaded by evaluate with ``evaluate.dirichlet.n_ss``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.infra.config import to_dict
from pipeline.infra.config.fields import setting as _f
from pipeline.infra.cost import ROW_S, Term, n_targets
from pipeline.method import dirichlet as D
from pipeline.method import dirichlet_fusion as DF
from pipeline.method.method_base import FusionMethod, TrackInput, register
from pipeline.method.provider import ModelProvider, Section, register_provider

DIRICHLET = "dirichlet"   # the method's and its provider's key (stored in results; models/dirichlet/)


# -- its config sections: [models.dirichlet] and [evaluate.dirichlet] ------------------------------
@dataclass(frozen=True)
class DirichletFitConfig:
    passes: str = _f("deterministic", choices=("deterministic", "dropout", "both"),
                     doc="BigBIRD passes each class's Dirichlet is fitted on: the deterministic pass (as Tchuiev & "
                         "Indelman did), the MC-dropout passes (features.bigbird_samples > 0), or both")
    floor: float = _f(1e-6, lo=1e-300, hi=1e-2,
                      doc="every probability entry is raised to at least this and the vector renormalised before "
                          "the log (fit and likelihood): a softmax entry that underflowed to 0 would veto a class")
    tol: float = _f(1e-10, lo=0.0, hi=1e-2, doc="fixed point stops when no theta_j changes by more than this, relatively")
    max_iter: int = _f(20000, lo=1, hi=10000000, doc="cap on steps of the fixed-point map; a fit that reaches it is "
                                                      "logged as a warning and marked in models/dirichlet/index.json")
    accelerate: bool = _f(True, doc="SQUAREM extrapolation of the same fixed-point map (nearly alike vectors need "
                                    "tens of thousands of plain steps); false = the plain iteration")
    entries: int = _f(0, lo=0, hi=1000,
                      doc="0 = the Dirichlet models the whole score vector; n > 0 = per candidate set, each "
                          "class's Dirichlet is fitted on (the set's first n chosen components, the rest mass) and "
                          "the evaluate stage uses those (for 1000-way ImageNet outputs)")


@dataclass(frozen=True)
class DirichletEvalConfig:
    n_ss: int = _f(100, lo=1, hi=1000000, doc="N_ss: posterior-cloud points kept after each step (Dirichlet method)")


# The Dirichlet fits' cost (DirichletProvider.fit_cost): seconds a step of the fixed point and per
# entry of the vectors, typical steps a fit, the entries of an ImageNet head's scores.
STEP_S, STEP_DIM_S, DIRICHLET_STEPS, IMAGENET_CLASSES = 4e-4, 1e-5, 12, 1000


@register_provider
class DirichletProvider(ModelProvider):
    key = DIRICHLET
    label = "Dirichlet class models"
    sections = {"models.dirichlet": DirichletFitConfig, "evaluate.dirichlet": DirichletEvalConfig}

    def check(self, cfg, need) -> None:
        d = cfg.models.dirichlet
        need(d.entries <= cfg.models.n_components,
             f"'models.dirichlet.entries' = {d.entries} exceeds 'models.n_components' = "
             f"{cfg.models.n_components}: it keeps that many of the chosen components")
        need(d.passes == "deterministic" or cfg.features.bigbird_samples > 0,
             f"'models.dirichlet.passes' = {d.passes!r} needs MC-dropout passes of the BigBIRD views "
             "('features.bigbird_samples' > 0)")

    def cost(self, cfg, rows: float) -> list:
        """Not measured apart: one method's share (1/6) of ROW_S at N_ss = 100, linear in N_ss."""
        n_ss = cfg.evaluate.dirichlet.n_ss
        return [Term("the Dirichlet method's posterior clouds", ("evaluate.dirichlet.n_ss",),
                     seconds=rows * ROW_S * n_ss / 100 / 6)] if n_ss > 0 else []

    def fit_cost(self, cfg, classes: int) -> list:
        """Minka's fixed point, per fit min(max_iter, DIRICHLET_STEPS) steps of STEP_S + STEP_DIM_S
        x D seconds (D: the score vector's entries; timed: 0.45 ms a step at D = 5, 10.6 ms at
        D = 1000, 128 vectors, 2-core AMD EPYC at load ~5), DIRICHLET_STEPS the cost of a fit that
        converges (0.12 s at D = 1000: 17-19 accelerated iterations). Scores so alike that the map
        crawls take up to max_iter steps (20,000 x 10 ms at D = 1000): the data decides, so the
        estimate is the converging fit's, and the term names the cap."""
        d = cfg.models.dirichlet
        dim = classes if cfg.classifier.weights == "synthetic" else IMAGENET_CLASSES
        steps = min(d.max_iter, DIRICHLET_STEPS)
        n_sets = (n_targets(cfg) * cfg.evaluate.n_candidates) if d.entries else 0
        secs = steps * (classes * (STEP_S + STEP_DIM_S * dim) + n_sets * (STEP_S + STEP_DIM_S * (d.entries + 1)))
        return [Term(f"the Dirichlet fits ({classes} classes at {dim} entries + {n_sets} set fits, about {steps} "
                     f"steps each if they converge; at most {d.max_iter})", ("models.dirichlet.max_iter", "models.dirichlet.entries", "models.classes"),
                     seconds=secs)]

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

    def section(self, index: dict) -> Section | None:
        """One row per class model (models/dirichlet/index.json)."""
        if not isinstance(index, dict) or not index.get("diagnostics"):
            return None
        fit, diags = index.get("fit") or {}, index["diagnostics"]
        text = ("{label}: {n} class models Dir(γ; θ_c) over the {dim} classifier outputs, fitted on the {passes} "
                "pass(es) of each class's BigBIRD views by maximum likelihood ({how}, tolerance {tol}); {bad} did "
                "not converge within {max_iter} steps. Entries below {floor} are raised to it.")
        values = {"label": Dirichlet.label, "n": len(diags), "dim": index.get("dim", "?"),
                  "passes": fit.get("passes", "?"), "how": fit.get("method", "fixed point"), "tol": fit.get("tol"),
                  "bad": sum(1 for d in diags if not d.get("converged")), "max_iter": fit.get("max_iter", "?"),
                  "floor": index.get("floor")}
        rows = tuple((d.get("class"), d.get("n"), d.get("precision"), d.get("iterations"),
                      "yes" if d.get("converged") else "no", d.get("log_likelihood")) for d in diags)
        return Section(text, values, ("class", "vectors", "precision Σθ", "fixed-point steps", "converged",
                                      "log likelihood"), rows, caption="Dirichlet class models from "
                       "models/dirichlet/index.json.", collapsed=f"All {len(rows)} Dirichlet fits", cls="dirichlet-fits")

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

    def report_note(self, block: dict | None) -> tuple[str, dict]:
        """What the comparison with it isolates, and how wide its posterior cloud is."""
        text = ("{short} (Tchuiev & Indelman 2018) fits one Dirichlet per class to the classifier's whole "
                "probability vector (every output, where the GP methods model their few chosen score components) "
                "and fuses the MC-dropout samples as a cloud of posterior vectors. Like Simple Bayes it ignores the "
                "poses: its posterior is the same for every localization realization and setting of a track, so "
                "With Uncertainty − Dirichlet measures what the viewpoint-dependent models (with the pose handling) "
                "add over a view-independent model that also accounts for model uncertainty.")
        spread = (block or {}).get("truth_std_final") or {}
        if spread:
            text += (" Its posterior cloud ({n_ss} points) has a median std of P(truth) at the final step of {median} "
                     "(quartiles {q25}–{q75}, max {max}) over {n_cells} tracks.")
        return text, {"short": self.short, "n_ss": (block or {}).get("n_ss"),
                      **{k: spread.get(k) for k in ("median", "q25", "q75", "max", "n_cells")}}
