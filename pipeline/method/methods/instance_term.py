"""The class models with an instance term (``pipeline/method/gp_instance.py``; docs/design.md §5,
"Instances differ"), the own model of With Uncertainty + instance and Model Based + instance: a
GP bank of the default candidate plan whose classes of two or more training objects add a deviation
of the unseen instance, shared by every view of a track.

``models.instance_term = true`` (a key of ``[models]`` this provider declares) turns it on: the
models stage fits it with the default bank's plan, training sets, settings and fit cache
(``TrainingViews.fit_bank``) into ``models/instance_term/``; evaluate narrows it to each cell's
candidates and components and puts it under the cell's test-domain variance, for the default
model bank's variants only (``default_only``: a models.* ablation or the contrast's instance arm
runs without it, as its plan or settings differ). ``OnInstanceModels`` turns a method on the GP
bank into the same method on these models.
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.infra.config.fields import setting as _f
from pipeline.infra.config.own import Key
from pipeline.method.gp import INDEX
from pipeline.method.gp_files import load_bank, read_bank_index, save_bank
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.gp_instance_fit import INSTANCE_PRIORS, fit_instance_models
from pipeline.method.method_base import TrackInput
from pipeline.method.provider import Interval, ModelProvider, Section, Spread, register_provider

INSTANCE_TERM = "instance_term"   # the provider's key: TrackInput.models, models/instance_term/, [models] key
FITTED = "instance_term"          # a fit record's flag: the class fitted a term (gp_instance_fit)
PRIOR = "instance_prior"          # [models] instance_prior, instance_prior_alpha, instance_prior_beta


@dataclass(frozen=True)
class InstanceBank:
    """The bank with an instance term as evaluate loads it: the models and their candidate plan
    ({target: {"classes", "components"}}, from its index)."""
    models: InstanceGPClassModels
    plan: dict


def fit_with_term(fit_bank, **prior) -> tuple[InstanceGPClassModels, dict]:
    """The candidate plan's bank with an instance term: ``fit_bank`` (``TrainingViews.fit_bank``)
    with the joint instance fit (``pipeline.method.gp_instance_fit``; a class of one training object
    gets no term; ``prior``: its ``instance_prior`` and ``split_prior``) -> (the bank, its index
    extras with ``instances``: each class's member objects)."""
    instances: dict[str, list[str]] = {}

    def fit(Xs, Ys, *, classes, members, **settings):
        instances.update({c: sorted(set(map(str, m))) for c, m in zip(classes, members)})
        return fit_instance_models(Xs, Ys, instances_by_class=members, classes=classes, **settings, **prior)

    models, extra = fit_bank(fit)
    extra["instances"] = instances
    return models, extra


@register_provider
class InstanceTermProvider(ModelProvider):
    key = INSTANCE_TERM
    label = "class models with an instance term"
    sections = {f"models.{INSTANCE_TERM}": Key(bool, _f(
        False, doc="also fit class models with an instance term on each class's member objects "
                   "(models/instance_term/; pipeline/method/gp_instance.py): the methods "
                   "with_uncertainty_instance and model_based_instance read them")),
        f"models.{PRIOR}": Key(str, _f(
            "split", choices=INSTANCE_PRIORS,
            doc="the instance fit's prior on its own terms (pipeline/method/gp_instance_fit.py): 'split' = a "
                "Beta(instance_prior_alpha, instance_prior_beta) law on b / (a + b) and the length scale's "
                "inverse-gamma range on λ (the default: docs/results.md, 'Instance term: a prior on the variance "
                "split'); 'none' = none on b and λ (fits run to their bounds)")),
        f"models.{PRIOR}_alpha": Key(float, _f(2.0, lo=1e-3, hi=1e3, doc="Beta shape alpha of b / (a + b) "
                                                                       "(instance_prior = 'split')")),
        f"models.{PRIOR}_beta": Key(float, _f(2.0, lo=1e-3, hi=1e3, doc="Beta shape beta of b / (a + b) "
                                                                      "(instance_prior = 'split')"))}
    default_only = True

    def enabled(self, cfg) -> bool:
        return bool(getattr(cfg.models, INSTANCE_TERM))

    def fit(self, views, cfg):
        if views.fit_bank is None:
            raise views.error("the class models with an instance term need the GP bank's training sets "
                              "(TrainingViews.fit_bank)")
        m = cfg.models
        return fit_with_term(views.fit_bank, instance_prior=getattr(m, PRIOR),
                             split_prior=(getattr(m, f"{PRIOR}_alpha"), getattr(m, f"{PRIOR}_beta")))

    def save(self, models, folder: Path, extra: dict) -> None:
        save_bank(models, folder, extra=extra)

    def load(self, folder: Path, cfg) -> InstanceBank:
        """The bank and its plan, which must be the default bank's (``models/index.json`` beside)."""
        models, index = load_bank(folder), read_bank_index(folder)
        if not isinstance(models, InstanceGPClassModels):
            raise ValueError(f"{folder}: not a bank with an instance term (rerun the models stage)")
        plan = index.get("candidate_sets") or {}
        mine = _sets(plan)
        default = _sets(read_bank_index(folder.parent).get("candidate_sets") or {}) \
            if (folder.parent / INDEX).is_file() else mine
        differ = sorted(t for t in set(mine) | set(default) if mine.get(t) != default.get(t))
        if differ:
            raise ValueError(f"{folder}: the instance bank's candidate sets differ from the default bank's for "
                             f"{len(differ)} target(s) (first: {differ[0]}; rerun the models stage)")
        return InstanceBank(models, plan)

    def digest(self, models) -> str:
        return models.digest()

    def record(self, models, extra: dict) -> dict:
        with_term = sum(bool(d[FITTED]) for d in extra["diagnostics"])
        return {"with_term": with_term, "without": len(extra["diagnostics"]) - with_term}

    def summary(self, models, extra: dict, cfg) -> str:
        r = self.record(models, extra)
        return (f"{r['with_term'] + r['without']} class-model fits for the instance term, {r['without']} without one "
                f"(a class of one training object)")

    def for_cell(self, bank: InstanceBank, target: str, classes: tuple[str, ...], dim: int):
        """The candidates' models at the target's components of the default plan."""
        p = bank.plan.get(target)
        if p is None or tuple(p["classes"]) != tuple(classes):
            raise ValueError(f"the instance bank plans {None if p is None else p['classes']} for the candidates "
                             f"{list(classes)}")
        comps = tuple(p["components"])
        if comps and max(comps) >= dim:
            raise ValueError(f"{dim} scores per crop, the instance bank models component {max(comps)}")
        return bank.models.subset(classes, comps)

    def calibrated(self, models, variance: np.ndarray):
        return models.with_test_variance(np.asarray(variance, float)[None, :])

    def serves(self, models) -> bool:
        return isinstance(models, InstanceGPClassModels)

    def section(self, index: dict) -> tuple[Section, ...] | None:
        """What the fits found (amplitude b, length scale λ, b over the class amplitude a) per category
        and per component, every fit in a collapsed table, and which classes got no term and why:
        every number from models/instance_term/index.json, nothing recomputed but quartiles."""
        fits = [d for d in (index or {}).get("diagnostics") or [] if isinstance(d, dict)]
        if not fits:
            return None
        s, cats = fit_summary(fits), index.get("categories") or {}
        text = ("Each class and component: s_i(θ) = m + g(θ) + h_i(θ) + ε, the instance deviation h_i with amplitude "
                "b and length scale λ, fitted on the class's training instances (models/instance_term/index.json). "
                "Of the {n} fits (class × component), {fitted} have two or more training instances and fit a term; "
                "in {at_floor} of them b sits at its lower bound (no term in effect; {both} of those with the class "
                "amplitude a at its lower bound too: a component that barely varies for that class). In the other "
                "{active}, b / a has median (quartiles) {ratio} and λ {scale} (a long λ: a constant offset per "
                "instance; a ratio far above 1: the held-out instance's own deviation dominates its predictive).")
        values = {"n": len(fits), "fitted": len(s["fitted"]), "at_floor": len(s["at_floor"]),
                  "both": len(s["both_at_floor"]), "active": len(s["active"]),
                  "ratio": Spread.of(d.get("instance_ratio") for d in s["active"]),
                  "scale": Spread.of(d.get("instance_length_scale") for d in s["active"])}
        out = [Section(text, values, title="Class models with an instance term: what the fits found",
                       anchor="instance-fits", note=False)]
        if s["no_term"]:
            out.append(Section("No instance term: " + "; ".join(f"{c} ({why})" for c, why in sorted(s["no_term"].items()))
                               + "."))
        note = ("Median (25–75 % quartiles) over the fits whose instance amplitude left its lower bound: descriptive "
                "spreads of fitted values, not confidence intervals (each fit's Laplace 95 % interval of b is in the "
                "per-fit table).")
        for name, group, caption in (("category", lambda d: str(cats.get(str(d.get("class")), d.get("class"))),
                                      "Instance fits per category (its fold classes together). "),
                                     ("component", _component, "Instance fits per score component, over the classes. ")):
            out.append(Section("", columns=(name, *GROUP_HEADER), rows=_group_rows(fits, s["fitted"], group),
                               caption=caption + note, cls=f"instance-fits-{name}"))
        rows = tuple((d.get("class"), _component(d), d.get("n_instances"), d.get("amplitude"),
                      d.get("instance_amplitude"), Interval.of(d.get("instance_amplitude_ci")),
                      d.get("instance_length_scale"), d.get("instance_ratio"),
                      "; ".join(d.get("at_bound") or []) or (d.get("instance_note") or "—")) for d in fits)
        out.append(Section("", columns=("class", "component", "training instances", "class amplitude a",
                                        "instance amplitude b", "b: 95 % interval (Laplace)", "instance length scale λ",
                                        "b / a", "at a bound / note"), rows=rows, cls="instance-fits",
                           collapsed=f"All {len(rows)} instance fits",
                           caption="Per (class, component), from models/instance_term/index.json. The interval of b "
                                   "varies over training sets drawn from the fitted model (Laplace approximation on "
                                   "the log scale)."))
        return tuple(out)


def _sets(plan: dict) -> dict:
    """{target: (candidate classes, components)} of a candidate plan."""
    return {t: ((p or {}).get("classes"), (p or {}).get("components")) for t, p in plan.items()}


GROUP_HEADER = ("fits", "with a term fitted", "instance amplitude at its lower bound", "instance amplitude b",
                "instance length scale λ", "b / class amplitude a")


def _at_lower(d: dict, name: str) -> bool:
    return f"{name} at lower bound" in (d.get("at_bound") or [])


def _component(d: dict) -> str:
    return str(d.get("component_name") or d.get("component"))


def fit_summary(fits: list[dict]) -> dict:
    """The instance fits' records: ``fitted`` (a term fitted), ``at_floor`` (fitted, amplitude at its
    lower bound: no term in effect), ``both_at_floor`` (the class amplitude too), ``active`` (the
    others), ``no_term`` ({class: why}: too few training instances)."""
    fitted = [d for d in fits if d.get(FITTED)]
    at_floor = [d for d in fitted if _at_lower(d, "instance_amplitude")]
    no_term: dict[str, str] = {}
    for d in fits:
        if not d.get(FITTED):
            no_term.setdefault(str(d.get("class")), d.get("instance_note") or "no instance term")
    return {"fitted": fitted, "active": [d for d in fitted if d not in at_floor], "at_floor": at_floor,
            "both_at_floor": [d for d in at_floor if _at_lower(d, "amplitude")], "no_term": no_term}


def _group_rows(fits: list[dict], fitted: list[dict], group) -> tuple[tuple, ...]:
    """One row per group (every group with a fit, a term fitted or not)."""
    n_fits, by = defaultdict(int), defaultdict(list)
    for d in fits:
        n_fits[group(d)] += 1
    for d in fitted:
        by[group(d)].append(d)
    rows = []
    for name in sorted(n_fits):
        mine = by.get(name, [])
        on = [d for d in mine if not _at_lower(d, "instance_amplitude")]
        rows.append((name, n_fits[name], len(mine), len(mine) - len(on),
                     Spread.of(d.get("instance_amplitude") for d in on),
                     Spread.of(d.get("instance_length_scale") for d in on),
                     Spread.of(d.get("instance_ratio") for d in on)))
    return tuple(rows)


class OnInstanceModels:
    """Put before a method's class (``class X(OnInstanceModels, ModelBased)``): the same method on
    the class models with an instance term (``TrackInput.models[INSTANCE_TERM]``) in place of
    ``gp``; it applies only where the cell carries them."""
    needs = frozenset({INSTANCE_TERM})
    simulation = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        return super().fuse(replace(t, gp=t.models[INSTANCE_TERM]))

    def single_view(self, t: TrackInput) -> np.ndarray:
        return super().single_view(replace(t, gp=t.models[INSTANCE_TERM]))

    def fuse_tracks(self, t: TrackInput) -> np.ndarray:
        return super().fuse_tracks(replace(t, gp=t.models[INSTANCE_TERM]))
