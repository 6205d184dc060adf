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
``tests/bench/bench_cost.py`` re-measures the constants on the machine it runs on.
"""
from __future__ import annotations

import logging
import resource
from dataclasses import dataclass

from pipeline.infra import footprints
from pipeline.infra.budget import (GIB, MemoryBudgetError, address_space_left, budget, budget_words, gib,
                                   more_memory)
from pipeline.infra.config.checks import modelled_classes
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.learning import early_epochs_run
from pipeline.infra.progress import duration
from pipeline.infra.registry import Registry
from pipeline.infra.datasets import dataset_source

log = logging.getLogger("viewfuse")

# --- per-unit seconds ---------------------------------------------------------------------------
# One With Uncertainty trajectory of K = 9 steps over C = 4 candidates: 32,000 trajectories/s in the
# paper-grade evaluate run (docs/benchmarks.md, "the paper-grade preset"). Cost grows as K^1.5 and
# linearly in C: bench_cost.py measured 2.8 and 3.2 times the (9, 4) cost at K = 18, and 1.7 and 3.2
# times at C = 8, in two runs under loads of 9 and 6 on the 2 cores (the ratios, not the level,
# set the scaling; the level there was 2-3x slower than this constant).
WU_TRAJECTORY_S = 1 / 32_000
# Everything else per (cell, realization, step): Model Based and the other methods, metrics, rows,
# writing: 28 s over 83 tracks x 2001 realizations x 9 steps in the same run.
ROW_S = 28 / (83 * 2001 * 9)
# Model Based on one one-step track (the bias maps: steps^2 per view): 15 s over the same run's
# 83 x 2001 x 9 trajectory-steps.
MB_STEP_S = 15 / (83 * 2001 * 9)
# View planning, per episode step (the belief update on the history) at N_x ~ 37 and C = 4: 20.6 s
# over 540 episodes of at most 10 steps on the default run; one information-gain decision at 64
# draws per class, horizon 1: 2.8 ms median (docs/benchmarks.md, "View planning"). A step grows with
# the history as K^1.5 (the budget, calibrated at 10), with N_x and with C; a decision with the draws,
# C and the nodes within the horizon.
PLAN_STEP_S = 20.6 / (540 * 10)
PLAN_DECISION_S = 2.8e-3
PLAN_MOVES = 6  # moves from an AVD node (forward, backward, left, right, rotate cw, ccw): the horizon's branching
# simulate (bench_cost.py, load 6 on 2 cores): a model_uncertainty realization of K = 21 steps
# 1.44 ms at 20 measurement samples (split 1.2 ms + 0.012 ms a sample from 80 samples' 3.9 ms at
# load 9); a localization_bias realization 34 ms at 100 localization samples (65 and 142 ms at 100
# and 200 under load 9: linear in them); the GP fits 4.0 s per (restarts + 1); a sweep point 0.5 s
# on top of its realizations (the small sweep's 20 s, docs/benchmarks.md).
SIM_MU_S, SIM_MU_SAMPLE_S, SIM_LB_SAMPLE_S, SIM_FIT_S, SIM_SWEEP_POINT_S = 1.2e-3, 1.2e-5, 3.4e-4, 4.0, 0.5
# The classifier (AlexNet, `viewfuse classifier`, idle Xeon 2.8 GHz, 2 cores, docs/benchmarks.md):
# 19 s to render 7600 source images; an epoch of 6400 images at 112 px and batch 64, 44 s; an early
# epoch (80 px crops, the compact head) 26 s, scaled by the area of their sides.
CLASSIFIER_RENDER_IMAGE_S = 19 / 7600
CLASSIFIER_IMAGE_EPOCH_S = 44 / 6400
CLASSIFIER_EARLY_EPOCH_SHARE = 26 / 44
# The features stage's MC-dropout head: 1.5 ms a (crop, sample) row, and the backbone 9.4 ms a
# 112 px crop (bench_cost.py: AlexNet, load 6 on 2 cores; 4.3 and 34 ms under load 9).
HEAD_ROW_S, BACKBONE_CROP_S = 1.5e-3, 9.4e-3
# Other networks, as a share of AlexNet's cost a crop at the same size and samples: EfficientNet-Lite0's
# head is one 1280-wide layer, not AlexNet's two 4096-wide ones (real_full idle: 213 s for 16,374
# crops at 160 px, 1 + 10 passes, with the stage's fixed work: 12 ms a crop against AlexNet's 36).
ARCH_CROP_SHARE = {"alexnet": 1.0, "efficientnet_lite0": 0.35}
# The data stage: 54 CPU s for the default synthetic world (the main job's row in docs/benchmarks.md,
# Xeon idle, 28 s wall), counted against its 1887 BigBIRD megapixels (AVD frames included).
RENDER_MP_S = 54 / (12 * 120 * 1280 * 1024 / 1e6)
# The data stage of photographs on real AVD geometry (real_imagery, turntable sources): real_full
# idle 69 s for 16,374 training views and frames read, pasted, degraded and encoded, less the
# stage's fixed work (docs/benchmarks.md, "Current figures"; 4.3 min before the writers were batched).
WRITE_IMAGE_S = 59 / 16_374
# The models stage: 8-10 s a seed for 12 classes x 4 components x 120 views x (5 restarts + 1)
# (make study): one GP fit a (class, component, start). A fit's cost grows as its views^1.6 over
# 36-128 views (artifacts/fitbench.py on the 2-core AMD EPYC, load 4.6: 3.1 ms at 36 views, 22 ms
# at 120, 26 ms at 128, a fit per (class, component, start) of fit_class_models).
MODEL_FIT_S = 9 / (12 * 4 * 6)
MODEL_FIT_VIEWS_POWER = 1.6
# The components fitted are the union of each candidate set's top models.n_components: 11-14 with
# n_components = 4 over 12 and over 72 candidate sets (the crops and likelihood branches' real runs:
# the sets' top scores overlap), 5 over the smoke run's 5 sets of 2 (at most n_components x sets).
UNION_COMPONENTS_SHARE = 3

# --- the stages' processes, before their work ----------------------------------------------------
# Resident bytes after importing every project module a stage reaches (its code version's module
# list) with their libraries: python -c "import ...; psutil rss" here. The torch stages map about
# 3.5 GiB of address space for that (what an RLIMIT_AS must leave room for); the others 0.7 GiB.
BASE = {"data": 0.14 * GIB, "classifier": 0.58 * GIB, "features": 0.60 * GIB, "models": 0.67 * GIB,
        "evaluate": 0.74 * GIB, "report": 0.72 * GIB, "simulate": 0.24 * GIB}
BASE_MAPPED = {"data": 0.7 * GIB, "simulate": 0.75 * GIB}
TORCH_MAPPED = 3.5 * GIB

# --- the stages' fixed work: seconds whatever the settings ---------------------------------------
# Process start and imports, pools started, models loaded, the outputs written, and per stage what
# no key multiplies: the smallest chain (configs/smoke.toml), idle, is almost nothing but this
# (docs/benchmarks.md: data 16 s, classifier 33 s, features 26 s, models 7 s, evaluate 41 s on the
# Xeon and 63-69 s on the AMD EPYC, report 29 s), and the real chains' stages with little work
# (real: classifier 3 s with ImageNet weights, models 6 s, report 10 s) bound it from below. Each
# is set so both sides lie within a factor of two (tests/stages/test_smoke_run.py checks the smoke
# chain's manifests against the estimates).
FIXED_S = {"data": 10.0, "classifier": 25.0, "features": 15.0, "models": 8.0, "evaluate": 40.0,
           "report": 16.0, "simulate": 5.0}
FIXED_LOADED_WEIGHTS_S = 3.0   # the classifier stage with weights it only loads (imagenet, path)


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


def register_terms(name: str, fn, *, module: str) -> None:
    EXTRA_TERMS.add(name, fn, module=module, replace=EXTRA_TERMS.peek(name) is not None
                    and EXTRA_TERMS.module_of(name) == module)


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
    for terms in EXTRA_TERMS.values():   # what each method's own model adds (ModelProvider.cost)
        out += terms(cfg, cells * reals * K)
    out.append(Term(f"the two-level bootstrap over {T} targets x up to {tracks} tracks", ("evaluate.bootstrap",),
                    bytes=footprints.bootstrap(ev.bootstrap, T, tracks)))
    return out


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
    variants = 1 + sum(1 for a in cfg.evaluate.ablations if a.strip().startswith("models."))
    comps = fitted_components(cfg)
    return [Term(f"the GP fits ({classes} classes x about {comps} components x {per_class:.0f} views x "
                 f"{m.restarts + 1} starts x {variants} bank(s))",
                 ("models.restarts", "models.classes", "models.n_components", "models.components", "evaluate.ablations"),
                 seconds=variants * classes * comps * (m.restarts + 1) * MODEL_FIT_S
                 * (per_class / 120) ** MODEL_FIT_VIEWS_POWER)]


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


