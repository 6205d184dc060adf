"""One cost model: every setting that multiplies a stage's work feeds one estimate of the stage's
seconds and peak bytes, checked before the stage starts (``check``): refused above
``run.max_minutes`` or the memory budget (``pipeline.infra.budget``) with the keys and the
estimate, a config error (exit 2). docs/design.md §2 ("One cost model").

An estimate is a list of ``Term`` s, one per kind of work (the population grid, the sensitivity
sweep, the planning episodes, ...), each naming the keys that multiply it, plus the stage's
``BASE`` (its process with its imports, before any work). Pure formulas of config values and of
counts the config implies, so a refusal costs nothing; the runner checks every stage a command
will run before the first one starts, and a stage may check again with counts only its input
says (evaluate: its targets and tracks, the bootstrap's timed draw).

The per-unit constants below are seconds of one unit of work on the development machine (2
cores, AMD EPYC), each with where it was measured. They are meant to be right within a small
factor: a faster machine takes less, a loaded one more, so a refusal says "about". Where a
count is unknown before the data exists (real data with ``targets = 'all'``), the estimate takes
the smallest count (one), so it never refuses what might fit. The data and features counts are
the dataset source's (``DatasetSource.work``: views and crops from its config), and so are the
views a class model is fitted on (``Work.views_per_class``; BigBIRD's 120 where not said); a part
a source does not declare is a term of 0 seconds that says "not estimated", logged once.
The constants live in ``pipeline/infra/cost_units.py``; ``tests/bench/bench_cost.py`` re-measures
them on the machine it runs on.
"""
from __future__ import annotations

import logging
import resource
from dataclasses import dataclass

from pipeline.infra import footprints
from pipeline.infra.budget import (MemoryBudgetError, address_space_left, budget, budget_words, gib,
                                   more_memory)
from pipeline.infra.config.checks import modelled_classes
from pipeline.infra.config.evaluation import cluster_of, fit_only_banks, is_model_ablation
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.learning import early_epochs_run
from pipeline.infra.cost_units import (WU_TRAJECTORY_S, ROW_S, MB_STEP_S, CELL_S, DOMAIN_UNIT_S, STAT_UNIT_S,
                                        STUDENT_T_SHARE, PLAN_STEP_S, PLAN_DECISION_S, PLAN_MOVES, SIM_MU_S,
                                        SIM_MU_SAMPLE_S, SIM_LB_SAMPLE_S, SIM_FIT_S, SIM_SWEEP_POINT_S,
                                        CLASSIFIER_RENDER_IMAGE_S, CLASSIFIER_IMAGE_EPOCH_S,
                                        CLASSIFIER_EARLY_EPOCH_SHARE, HEAD_ROW_S, BACKBONE_CROP_S,
                                        ARCH_CROP_SHARE, RENDER_MP_S, WRITE_IMAGE_S, MODEL_FIT_S,
                                        MODEL_FIT_VIEWS_POWER, UNION_COMPONENTS_SHARE, BASE, BASE_MAPPED,
                                        TORCH_MAPPED, FIXED_S, FIXED_LOADED_WEIGHTS_S)
from pipeline.infra.progress import duration
from pipeline.infra.registry import Registry
from pipeline.infra.datasets import dataset_source

log = logging.getLogger("viewfuse")


@dataclass(frozen=True)
class Term:
    """One kind of work: what it is, the keys that multiply it, its seconds and the bytes it holds
    at its peak (on top of the stage's ``BASE``)."""
    what: str
    keys: tuple[str, ...]
    seconds: float = 0.0
    bytes: float = 0.0


@dataclass(frozen=True)
class Estimate:
    stage: str
    terms: tuple[Term, ...]
    base: float = 0.0
    mapped: float = 0.0  # address space the stage's imports map (checked against RLIMIT_AS)

    @property
    def seconds(self) -> float:
        return sum(t.seconds for t in self.terms)

    @property
    def peak(self) -> float:
        return self.base + max((t.bytes for t in self.terms), default=0.0)


# --- terms a method with a model of its own adds (pipeline/method/provider.py) -------------------
# name -> fn(cfg, rows) -> [Term], rows = the population grid's (cell, realization, step) rows,
# each ROW_S seconds for the methods measured together; loaded like the methods, in every process.
EXTRA_TERMS: Registry = Registry("cost term", "viewfuse.methods", "pipeline.method.methods")


# name -> fn(cfg, classes) -> [Term]: what fitting that provider's models adds to the models stage
# (ModelProvider.fit_cost), ``classes`` the classes the stage models.
FIT_TERMS: Registry = Registry("fit cost term", "viewfuse.methods", "pipeline.method.methods")


def register_terms(name: str, fn, *, module: str, fit=None) -> None:
    for reg, f in ((EXTRA_TERMS, fn), (FIT_TERMS, fit)):
        if f is not None:
            reg.add(name, f, module=module, replace=reg.peek(name) is not None and reg.module_of(name) == module)


# --- counts the config implies -------------------------------------------------------------------
@dataclass(frozen=True)
class Counts:
    """What multiplies the work besides the keys: targets and tracks per target (None = from the
    config: ``n_targets``; ``evaluate.tracks_per_target``, an upper bound) and AVD boxes."""
    targets: int | None = None
    tracks: int | None = None
    avd_crops: int = 0     # the AVD boxes the features stage scores (0: not known yet, a lower bound)


def n_targets(cfg) -> int:
    ev = cfg.evaluate
    if not isinstance(ev.targets, str):
        return len(ev.targets)
    classes = modelled_classes(cfg)
    return len(classes) if classes else 1   # real data, 'all': unknown until the features exist


def _wu_scale(k: int, c: int) -> float:
    return (k / 9) ** 1.5 * max(c, 1) / 4


def _value(cfg, key: str) -> str:
    v = cfg.section(key)
    if isinstance(v, (tuple, list)):
        return f"[{len(v)} entries]" if len(v) > 3 else "[" + ", ".join(map(str, v)) + "]"
    return str(v)


# --- the stages ----------------------------------------------------------------------------------
def evaluate_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    ev, plan = cfg.evaluate, cfg.plan
    T = counts.targets or n_targets(cfg)
    tracks = counts.tracks or ev.tracks_per_target
    K, C = ev.track_length, ev.n_candidates
    variants = 1 + len(ev.ablations) + int(ev.attribution)  # attribution: one more With Uncertainty pass
    trajectories, reals, keys = 0.0, 0.0, []
    if "biased" in ev.experiments:
        trajectories += ev.biased.n_loc_samples
        reals += 1
        keys += ["evaluate.biased.n_loc_samples"]
    if "randomized" in ev.experiments:
        r = ev.randomized
        trajectories += len(r.sigmas_m) * r.realizations * r.n_loc_samples
        reals += len(r.sigmas_m) * r.realizations
        keys += ["evaluate.randomized.realizations", "evaluate.randomized.n_loc_samples", "evaluate.randomized.sigmas_m"]
    if "biased_randomized" in ev.experiments:
        p = ev.biased_randomized
        trajectories += p.realizations * p.n_loc_samples
        reals += p.realizations
        keys += ["evaluate.biased_randomized.realizations", "evaluate.biased_randomized.n_loc_samples"]
    cells = T * tracks * variants
    common = ["evaluate.targets", "evaluate.tracks_per_target", "evaluate.ablations", "evaluate.attribution",
              "evaluate.track_length", "evaluate.n_candidates"]
    r = ev.randomized
    out = [Term(f"the population grid ({T} targets x {tracks} tracks x {variants} variant(s), "
                f"{trajectories * cells:.3g} With Uncertainty trajectories)", tuple(keys + common),
                seconds=cells * (trajectories * WU_TRAJECTORY_S * _wu_scale(K, C) + reals * K * ROW_S),
                bytes=footprints.fused_batch(max(r.n_loc_samples, ev.biased_randomized.n_loc_samples), K, C)),
           Term(f"one cell's results ({len(r.sigmas_m)} sigmas x {K} steps per realization)",
                ("evaluate.randomized.realizations", "evaluate.randomized.sigmas_m", "evaluate.track_length"),
                bytes=footprints.randomized_cell(ev, K, C) if "randomized" in ev.experiments else 0.0)]
    if "sensitivity" in ev.experiments:
        s = ev.sensitivity
        n = len(s.sigmas_m) * s.realizations
        rows = footprints.kept_rows(n, K, C)
        out.append(Term(f"the sensitivity sweep ({len(s.sigmas_m)} sigmas x {s.realizations} realizations x "
                        f"{s.n_loc_samples} localization samples)",
                        ("evaluate.sensitivity.realizations", "evaluate.sensitivity.n_loc_samples",
                         "evaluate.sensitivity.sigmas_m"),
                        seconds=n * (s.n_loc_samples * WU_TRAJECTORY_S * _wu_scale(K, C) + K * ROW_S),
                        bytes=rows + footprints.fused_batch(s.n_loc_samples, K, C)))
    if "bias_maps" in ev.experiments:
        out.append(Term(f"the bias maps ({ev.bias_maps.steps}^2 biases x {K} views)", ("evaluate.bias_maps.steps",),
                        seconds=ev.bias_maps.steps ** 2 * K * MB_STEP_S * C / 4))
    if plan.enabled:
        n_x = (ev.biased.n_loc_samples + ev.randomized.n_loc_samples) / 2
        episodes = T * plan.starts * 2 * 6      # 2 localization settings x 6 planners
        decisions = T * plan.starts * 2 * plan.budget * min(PLAN_MOVES ** (plan.horizon - 1), 10_000)
        out.append(Term(f"view planning ({episodes} episodes of up to {plan.budget} steps)",
                        ("plan.starts", "plan.budget", "plan.eig_samples", "plan.horizon", "evaluate.targets",
                         "evaluate.biased.n_loc_samples", "evaluate.randomized.n_loc_samples"),
                        seconds=episodes * plan.budget * PLAN_STEP_S * (n_x / 37.5) * (plan.budget / 10) ** 1.5 * C / 4
                        + decisions * PLAN_DECISION_S * (plan.eig_samples / 64) * C / 4))
    if ev.likelihood_tail == "student_t":
        out.append(Term("the Student-t variants of With Uncertainty and Model Based", ("evaluate.likelihood_tail",),
                        seconds=STUDENT_T_SHARE * out[0].seconds))
    out += fixed_evaluate_parts(cfg, T, tracks)
    for terms in EXTRA_TERMS.values():   # what each method's own model adds (ModelProvider.cost)
        out += terms(cfg, cells * reals * K)
    out.append(Term(f"the two-level bootstrap over {T} targets x up to {tracks} tracks", ("evaluate.bootstrap",),
                    bytes=footprints.bootstrap(ev.bootstrap, T, tracks)))
    return out


def model_banks(cfg) -> int:
    """The model banks a run fits (the models stage) and fits the test domain to (evaluate): the
    main one, each models.* ablation's and each fit-only one of evaluate.fit_spaces."""
    return 1 + sum(1 for a in cfg.evaluate.ablations if is_model_ablation(a)) + len(fit_only_banks(cfg))


def fixed_evaluate_parts(cfg, T: int, tracks: int) -> list[Term]:
    """The evaluate work beside the grid's trajectories: each cell's own, the test-domain fit on the
    labelled AVD crops and the population statistics (the constants' note: CELL_S, DOMAIN_UNIT_S,
    STAT_UNIT_S)."""
    ev = cfg.evaluate
    work = source_work(cfg)
    views = max(work.views_per_class if work is not None and work.views_per_class is not None else 120, 1)
    crops = (work.test_crops if work is not None else None) or 0
    comps = fitted_components(cfg)
    cells = T * tracks * (1 + len(ev.ablations))   # attribution runs inside a cell, an ablation is a cell
    banks = model_banks(cfg)   # each fits the test domain
    return [Term(f"the cells' own work ({cells} cells: targets x tracks x (1 + ablations))",
                 ("evaluate.targets", "evaluate.tracks_per_target", "evaluate.ablations"), seconds=cells * CELL_S),
            Term(f"the test-domain fit ({crops} AVD crops x about {comps} components x {views:.0f} views a class"
                 f" x {banks} model bank(s): the main one, each models.* ablation's and each fit-only one)",
                 ("data.scans", "models.n_components", "evaluate.ablations", "evaluate.fit_spaces"),
                 seconds=crops * comps * views * banks * DOMAIN_UNIT_S),
            Term(f"the population statistics ({T} targets x up to {tracks} tracks x {ev.bootstrap} resamples, "
                 f"clustered by {cluster_of(ev)})",
                 ("evaluate.bootstrap", "evaluate.targets", "evaluate.tracks_per_target", "evaluate.statistics.cluster"),
                 seconds=T * tracks * ev.bootstrap * STAT_UNIT_S * (1 if cluster_of(ev) == "target" else 2))]


def simulate_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    sim = cfg.simulate
    K = sim.track_steps
    per_mu = (SIM_MU_S + SIM_MU_SAMPLE_S * sim.n_samples) * (K / 21) ** 1.5
    per_lb = SIM_LB_SAMPLE_S * sim.n_loc_samples * (K / 21) ** 1.5
    rows = footprints.simulate_results(sim)
    out = [Term(f"the GP fits (3 classes x {sim.restarts + 1} starts)", ("simulate.restarts",),
                seconds=SIM_FIT_S * (sim.restarts + 1))]
    if "model_uncertainty" in sim.scenarios:
        out.append(Term(f"model_uncertainty ({sim.realizations} realizations x {K} steps x {sim.n_samples} samples)",
                        ("simulate.realizations", "simulate.track_steps", "simulate.n_samples"),
                        seconds=sim.realizations * per_mu, bytes=rows))
    if "localization_bias" in sim.scenarios:
        out.append(Term(f"localization_bias ({sim.realizations} realizations x {K} steps x {sim.n_loc_samples} "
                        "localization samples)",
                        ("simulate.realizations", "simulate.track_steps", "simulate.n_loc_samples"),
                        seconds=sim.realizations * per_lb, bytes=rows))
    if sim.sweep != "off":
        full = sim.sweep == "full"
        noise = sim.sweep_full_noise if full else sim.sweep_noise
        sig = sim.sweep_full_sigma_max if full else sim.sweep_sigma_max
        reals = sim.sweep_full_realizations if full else sim.sweep_realizations
        points = len(noise) * len(sig) + 1
        pre = "simulate.sweep_full_" if full else "simulate.sweep_"
        out.append(Term(f"the regime sweep ({points} points x {reals} realizations)",
                        ("simulate.sweep", pre + "noise", pre + "sigma_max", pre + "realizations"),
                        seconds=points * (SIM_SWEEP_POINT_S + reals * per_mu) + sim.realizations * per_mu))
    return out


def classifier_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    c = cfg.classifier
    t = c.training
    if c.weights != "synthetic":
        return []
    early = early_epochs_run(t.epochs, t.early_epochs, t.early_size, c.input_size)
    epochs = (t.epochs - early) + early * CLASSIFIER_EARLY_EPOCH_SHARE * (t.early_size / 80) ** 2 / (c.input_size / 112) ** 2
    return [Term(f"training ({t.train_images} + {t.val_images} images x {t.epochs} epochs at {c.input_size} px, "
                 f"{early} of them at {t.early_size} px)",
                 ("classifier.training.train_images", "classifier.training.val_images",
                  "classifier.training.epochs", "classifier.input_size", "classifier.training.early_epochs",
                  "classifier.training.early_size"),
                 seconds=(t.train_images + t.val_images) * CLASSIFIER_RENDER_IMAGE_S
                 + t.train_images * epochs * CLASSIFIER_IMAGE_EPOCH_S * (c.input_size / 112) ** 2,
                 bytes=footprints.classifier_training(c))]


def source_work(cfg):
    """What ``data.source`` declares it will write and score (``DatasetSource.work``), or None."""

    return dataset_source(cfg.data.source).work(cfg)


_UNESTIMATED: set = set()   # (source, stage, what): logged once a process, not on every check


def _not_estimated(cfg, stage: str, what: str) -> Term:
    """A part of a stage's work the source does not declare: logged, and a term of 0 seconds that
    says so (never a silent 0)."""
    words = f"{what}: not estimated (data.source = {cfg.data.source!r} does not say it from the config)"
    if (cfg.data.source, stage, what) not in _UNESTIMATED:
        _UNESTIMATED.add((cfg.data.source, stage, what))
        log.info("%s stage: %s", stage, words)
    return Term(words, ("data.source",))


def features_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    f = cfg.features
    work = source_work(cfg)
    size = (cfg.classifier.input_size / 112) ** 2
    share = ARCH_CROP_SHARE.get(cfg.classifier.arch, 1.0)
    out = []
    views = work.training_views if work else None
    if views is None:
        out.append(_not_estimated(cfg, "features", "scoring the BigBIRD views"))
    else:
        out.append(Term(f"scoring {views} BigBIRD views x (1 + {f.bigbird_samples} MC-dropout passes)",
                        ("features.bigbird_samples", *work.view_keys),
                        seconds=share * views * (BACKBONE_CROP_S * size + HEAD_ROW_S * (1 + f.bigbird_samples))))
    # the boxes found in the data (the stage's own check) over the source's count from its config
    crops = counts.avd_crops or (work.test_crops if work else None)
    if crops is None:
        out.append(_not_estimated(cfg, "features", "scoring the AVD boxes (the stage checks again with those found)"))
    else:
        behind = work.crop_keys if work and not counts.avd_crops else ("features.max_difficulty", "data.scans")
        out.append(Term(f"scoring {crops} AVD boxes x (1 + {f.n_samples} MC-dropout passes)",
                        tuple(dict.fromkeys(("features.n_samples", *behind))),
                        seconds=share * crops * (BACKBONE_CROP_S * size + HEAD_ROW_S * (1 + f.n_samples))))
    return out


def data_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    work = source_work(cfg)
    if work is None:
        return [_not_estimated(cfg, "data", "writing the run data")]
    out = []
    if work.rendered_megapixels:
        mp = work.rendered_megapixels
        out.append(Term(f"rendering {mp:.0f} megapixels of BigBIRD views on {work.render_workers} worker(s)",
                        work.data_keys,
                        seconds=mp * RENDER_MP_S / work.render_workers))
    if work.training_views is None and work.written:
        out.append(_not_estimated(cfg, "data", "writing the training views"))
    if work.written:
        out.append(Term(f"writing {work.written} images (training views and AVD frames)",
                        tuple(dict.fromkeys((*work.view_keys, *work.crop_keys, *work.data_keys))),
                        seconds=work.written * WRITE_IMAGE_S))
    return out


def models_terms(cfg, counts: Counts = Counts()) -> list[Term]:
    m = cfg.models
    classes = len(modelled_classes(cfg) or ()) or 1
    work = source_work(cfg)
    # what the source declares a class is fitted on; undeclared: a BigBIRD ring's 120 angles
    declared = work.views_per_class if work is not None else None
    per_class = max(declared if declared is not None else 120, 1)
    variants = model_banks(cfg)
    comps = fitted_components(cfg)
    extra = [t for fit in FIT_TERMS.values() for t in fit(cfg, classes)]   # each provider's own fits
    return [Term(f"the GP fits ({classes} classes x about {comps} components x {per_class:.0f} views x "
                 f"{m.restarts + 1} starts x {variants} bank(s))",
                 ("models.restarts", "models.classes", "models.n_components", "models.components", "evaluate.ablations",
                  "evaluate.fit_spaces"),
                 seconds=variants * classes * comps * (m.restarts + 1) * MODEL_FIT_S
                 * (per_class / 120) ** MODEL_FIT_VIEWS_POWER)] + extra


def fitted_components(cfg) -> int:
    """The score components each class is fitted on: the rule's list, or about the union of the
    candidate sets' top ``n_components`` (``UNION_COMPONENTS_SHARE``; a set per target)."""
    m = cfg.models
    if m.component_rule == "explicit":
        return max(len(m.components), 1)
    return m.n_components * min(UNION_COMPONENTS_SHARE, n_targets(cfg))


ESTIMATORS = {"data": data_terms, "classifier": classifier_terms, "features": features_terms,
              "models": models_terms, "evaluate": evaluate_terms, "simulate": simulate_terms}


def fixed_term(cfg, stage: str) -> Term:
    """The stage's fixed work (``FIXED_S``), a term like the others so a refusal lists it."""
    secs = FIXED_S.get(stage, 0.0)
    if stage == "classifier" and cfg.classifier.weights != "synthetic":
        secs = FIXED_LOADED_WEIGHTS_S
    return Term(f"the {stage} stage's fixed work (start-up, imports, loading, writing)", (), seconds=secs)


def estimate(cfg, stage: str, counts: Counts = Counts(), extra: tuple[Term, ...] = ()) -> Estimate:
    """The stage's estimate from its config (and ``counts`` where the caller knows them)."""
    fn = ESTIMATORS.get(stage)
    terms = (fixed_term(cfg, stage),) + tuple(fn(cfg, counts) if fn else ()) + tuple(extra)
    torch_stage = stage in ("classifier", "features", "models", "evaluate", "report")
    return Estimate(stage, terms, base=BASE.get(stage, 0.0),
                    mapped=TORCH_MAPPED if torch_stage else BASE_MAPPED.get(stage, 0.0))


def check(cfg, stage: str, counts: Counts = Counts(), extra: tuple[Term, ...] = (), base: bool = True) -> Estimate:
    """Refuse (a config error, exit 2) a stage whose estimate exceeds the memory budget or
    ``run.max_minutes``, naming the keys, their values and the estimate; return the estimate.
    ``base=False``: the work alone (a stage checking again from inside, its process long started)."""
    est = estimate(cfg, stage, counts, extra)
    if not base:
        est = Estimate(est.stage, est.terms)
    limit = budget(cfg)
    if est.base > limit:
        raise MemoryBudgetError(
            f"'run.memory_gb' = {cfg.run.memory_gb:g}: the {stage} stage's process alone (Python and the libraries "
            f"it imports, measured) holds about {gib(est.base)}, over the memory budget of {gib(limit)} "
            f"({budget_words()}); {more_memory(est.base)}")
    for t in est.terms:
        if est.base + t.bytes > limit:
            raise MemoryBudgetError(
                f"{_keys(cfg, t)}: {t.what} needs about {gib(est.base + t.bytes)}, over the memory budget of "
                f"{gib(limit)} ({budget_words()}{f'; with the {stage} stage process' if est.base else ''}); lower "
                f"{_names(t)} or {more_memory(est.base + t.bytes)}")
    left = address_space_left()
    if left is not None:
        import psutil
        mapped_now = psutil.Process().memory_info().vms
        need = max(est.mapped - mapped_now, 0) + max((t.bytes for t in est.terms), default=0.0)
        if need > left:
            soft = resource.getrlimit(resource.RLIMIT_AS)[0]
            raise MemoryBudgetError(
                f"the {stage} stage needs about {gib(need)} more address space (its libraries map about "
                f"{gib(est.mapped)}; its largest step {gib(need - max(est.mapped - mapped_now, 0))}), more than the "
                f"{gib(left)} the address-space limit (ulimit -v, RLIMIT_AS) of {gib(soft)} leaves; raise the limit "
                "or lower the settings")
    minutes = float(cfg.run.max_minutes)
    if minutes and est.seconds > 60 * minutes:
        top = sorted(est.terms, key=lambda t: -t.seconds)
        parts = "; ".join(f"{t.what}: about {duration(t.seconds)} ({_keys(cfg, t)})" for t in top if t.seconds >= 0.1 * est.seconds)
        raise ConfigError(
            f"the {stage} stage would take about {duration(est.seconds)}, over 'run.max_minutes' = {minutes:g}: {parts}. "
            f"Lower those keys or raise 'run.max_minutes' (0 = no limit); the estimate is pipeline/infra/cost.py's "
            "(per-unit seconds measured on a 2-core machine)")
    return est


def _names(t: Term) -> str:
    return ", ".join(f"'{k}'" for k in t.keys[:3])


def _keys(cfg, t: Term) -> str:
    return ", ".join(f"'{k}' = {_value(cfg, k)}" for k in t.keys)


def describe(est: Estimate) -> str:
    """One line: the estimate's seconds and peak, for the log before a long stage."""
    return f"about {duration(est.seconds)} and {gib(est.peak)} at its peak (pipeline/infra/cost.py)"


