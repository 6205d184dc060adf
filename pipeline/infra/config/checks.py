"""Config checks that span keys, for every section (``[simulate]`` included): run at load, so a bad
value stops ``viewfuse`` before any stage runs, with the file and the keys named.

``bounds_problem`` is the one check of a ``[low, high]`` hyperparameter range: the config, the GP
fits (``pipeline/method/gp_fit.py``) and the simulation use it.
"""
from __future__ import annotations

import math
import re

from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.evaluation import ABLATION_KEYS
from pipeline.infra.config.own import checks as own_checks
from pipeline.infra.config.root import Config, to_dict
from pipeline.infra.config.simulate import SimulateConfig
from pipeline.infra.datasets import dataset_source

# A run name is one folder name: nothing that could climb out of the artifacts folder (separators,
# "..", a leading dot that would hide it among the runner's temporary folders) or that the file
# system cannot hold (NUL).
RUN_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")
SIM_CLASSES = 3  # the simulation scenarios' three classes (pipeline/evaluation/simulation/scenarios.py)


# A classifier.arch: a registered name or <family>:<model>. What it names, and that entry's own
# checks, are the classifier registry's (pipeline/scoring/classifiers/registry.py check_config,
# run by the CLI after loading and by the classifier stage): the config does not import the networks.
ARCH_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.-]*(:[A-Za-z][A-Za-z0-9_.-]*)?")


def bounds_problem(b) -> str | None:
    """Why ``b`` is not a ``[low, high]`` range with 0 < low < high (finite), or None."""
    if len(b) != 2:
        return f"must be [low, high], got {len(b)} value(s)"
    lo, hi = float(b[0]), float(b[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        return f"must be [low, high] with 0 < low < high, got {list(b)}"
    return None


def check_run(cfg: Config, where: str) -> None:
    name = cfg.run.name
    if not RUN_NAME.fullmatch(name) or name.strip(".") == "":
        raise ConfigError(f"{where}: 'run.name' = {name!r} must be a plain folder name (letters, digits and "
                          "'._-', not starting with '.', at most 128 characters; no '/', '..' or NUL): "
                          "outputs go to <run.artifacts>/<run.name>/")
    if not cfg.run.artifacts.strip():
        raise ConfigError(f"{where}: 'run.artifacts' must not be empty")


def modelled_classes(cfg: Config) -> tuple[str, ...] | None:
    """The classes the models stage will model, when the config alone says (None with real data
    and models.classes = 'all': the dataset decides, and the stages name a missing target)."""
    if not isinstance(cfg.models.classes, str):
        return tuple(cfg.models.classes)
    return dataset_source(cfg.data.source).classes(cfg)


def _modelled_words(cfg: Config) -> str:
    if not isinstance(cfg.models.classes, str):
        return "'models.classes'"
    return (dataset_source(cfg.data.source).classes_words(cfg)
            or "'models.classes' = 'all': the objects of 'features.bigbird_objects' or, when empty, "
               "'data.synthetic.instances'")


def cross_checks(cfg: Config, where: str) -> None:
    """Checks that span keys; each names the keys involved."""
    def need(ok: bool, msg: str) -> None:
        if not ok:
            raise ConfigError(f"{where}: {msg}")

    check_run(cfg, where)
    cl = cfg.evaluate.statistics.cluster
    need(not cfg.evaluate.resample_scans or cl in ("target", "scan"),
         f"'evaluate.resample_scans' = true asks for scans on top, but 'evaluate.statistics.cluster' = {cl!r}: "
         "set only the cluster")
    need(cl != "category" or dataset_source(cfg.data.source, where).category_targets(to_dict(cfg.data)),
         "'evaluate.statistics.cluster' = 'category' needs category targets (data.source = 'real_imagery' "
         "with data.real_imagery.dataset = 'eth80', or a source that declares them)")
    s = cfg.data.synthetic
    need(s.angle_step_deg % 3 == 0, f"'data.synthetic.angle_step_deg' = {s.angle_step_deg} must be a multiple of 3 (BigBIRD angles are 0, 3, ..., 357)")
    need(360 % s.angle_step_deg == 0, f"'data.synthetic.angle_step_deg' = {s.angle_step_deg} must divide 360")
    need(all(1 <= c <= 5 for c in s.bigbird_cameras) and s.bigbird_cameras,
         "'data.synthetic.bigbird_cameras' must list cameras among 1..5")
    need(len(s.room_size_m) == 2 and min(s.room_size_m) > 0, "'data.synthetic.room_size_m' must be two positive numbers")
    need(len(set(s.instances)) == len(s.instances) and len(s.instances) >= 2,
         "'data.synthetic.instances' must list at least two distinct instance names")
    scans = cfg.data.scans
    need(len(scans) >= 1 and len(set(scans)) == len(scans), "'data.scans' must list at least one scan, each once")
    for sc in scans:  # each becomes a folder name under the data stage's output
        need(bool(RUN_NAME.fullmatch(sc)) and sc.strip(".") != "",
             f"'data.scans' names {sc!r}: a scan is one plain folder name (no '/', '\\', '..' or NUL)")
    need(all(1 <= c <= 5 for c in cfg.features.bigbird_cameras) and cfg.features.bigbird_cameras,
         "'features.bigbird_cameras' must list cameras among 1..5")
    dataset_source(cfg.data.source, where).check(cfg, need)   # the source's own checks
    need(cfg.models.camera in cfg.features.bigbird_cameras,
         f"'models.camera' = {cfg.models.camera} is not among 'features.bigbird_cameras'")
    for check in own_checks():   # the checks of the sections extensions declared (config/own.py)
        check(cfg, need)
    if cfg.classifier.weights == "path":
        need(bool(cfg.classifier.path), "'classifier.path' must be set when classifier.weights = 'path'")
    need(len(cfg.classifier.mean) == 3 and len(cfg.classifier.std) == 3,
         "'classifier.mean' and 'classifier.std' must list three (RGB) values each")
    need(bool(ARCH_NAME.fullmatch(cfg.classifier.arch)),
         f"'classifier.arch' = {cfg.classifier.arch!r} is not a classifier name (a registered name such as "
         "'alexnet', or 'torchvision:<model>')")
    if not isinstance(cfg.models.classes, str):
        need(len(set(cfg.models.classes)) == len(cfg.models.classes) and len(cfg.models.classes) >= 2,
             "'models.classes' must list at least two distinct classes")
    if cfg.models.component_rule == "explicit":
        need(len(cfg.models.components) == cfg.models.n_components,
             "'models.components' must list exactly 'models.n_components' indices for rule 'explicit'")
    need(cfg.models.targets != "dropout_mean" or cfg.features.bigbird_samples > 0,
         "'models.targets' = 'dropout_mean' needs MC-dropout passes of the BigBIRD views: set "
         "'features.bigbird_samples' > 0 or 'models.targets' = 'deterministic'")
    for key in ("amplitude_bounds", "length_scale_bounds", "noise_bounds", "noise_prior"):
        problem = bounds_problem(getattr(cfg.models, key))
        need(problem is None, f"'models.{key}' {problem}")
    ev = cfg.evaluate
    if not isinstance(ev.targets, str):
        need(len(ev.targets) >= 1 and len(set(ev.targets)) == len(ev.targets),
             "'evaluate.targets' must be 'all' or a list of distinct instance names")
        modelled = modelled_classes(cfg)
        for t in ev.targets:
            need(modelled is None or t in modelled,
                 f"'evaluate.targets' names {t!r}, which is not a modelled instance "
                 f"({_modelled_words(cfg)})")
    if ev.yaws_deg:
        need(not isinstance(ev.targets, str) and len(ev.yaws_deg) == len(ev.targets),
             "'evaluate.yaws_deg' must give one yaw per entry of 'evaluate.targets'")
    if ev.track_images:
        need(not isinstance(ev.targets, str) and len(ev.targets) == 1,
             "'evaluate.track_images' gives one track of one target: set 'evaluate.targets' to that one instance")
    if not isinstance(ev.candidates, str):
        need(len(set(ev.candidates)) == len(ev.candidates) and len(ev.candidates) >= 1,
             "'evaluate.candidates' must be 'sampled', 'all', 'hard' or a list of distinct class names")
    elif ev.candidates in ("sampled", "hard"):
        modelled = modelled_classes(cfg)
        need(modelled is None or ev.n_candidates <= len(set(modelled)),
             f"'evaluate.n_candidates' = {ev.n_candidates} exceeds the {len(set(modelled or ()))} modelled classes "
             f"({_modelled_words(cfg)}) that evaluate.candidates = {ev.candidates!r} draws from")
    dup = sorted({m for m in ev.primary_metrics if ev.primary_metrics.count(m) > 1})
    need(not dup, f"'evaluate.primary_metrics' lists {', '.join(map(repr, dup))} more than once")
    pm = ev.primary
    need(len(pm.methods) == 2 and pm.methods[0] != pm.methods[1],
         f"'evaluate.primary.methods' = {list(pm.methods)!r} must be [method, baseline], two different method keys")
    need(pm.setting == "all" or pm.setting in ("biased", "randomized", "biased_randomized") and pm.setting in ev.experiments,
         f"'evaluate.primary.setting' = {pm.setting!r} must be 'all' or an experiment of 'evaluate.experiments' "
         "with population settings (biased, randomized, biased_randomized)")
    need(pm.setting != "randomized" or len(ev.randomized.sigmas_m) == 1,
         "'evaluate.primary.setting' = 'randomized' names one setting only when 'evaluate.randomized.sigmas_m' "
         "lists one sigma: declare 'all' or another experiment")
    for a in ev.ablations:
        key = a.split("=", 1)[0].strip()
        need("=" in a and key in ABLATION_KEYS,
             f"'evaluate.ablations' entry {a!r} must be 'KEY=VALUE' with KEY one of {', '.join(ABLATION_KEYS)}")
        if key == "evaluate.test_domain_variance":
            need(a.split("=", 1)[1].strip().strip("'\"") in ("none", "cross_fit"),
                 f"'evaluate.ablations' entry {a!r}: the value must be none or cross_fit")
    dup = sorted({s for s in ev.fit_spaces if ev.fit_spaces.count(s) > 1})
    need(not dup, f"'evaluate.fit_spaces' lists {', '.join(map(repr, dup))} more than once (each bank is fitted once)")
    known = ("gp_models", "biased", "randomized", "biased_randomized", "sensitivity", "bias_maps")
    for e in cfg.evaluate.experiments:
        need(e in known, f"'evaluate.experiments' names unknown experiment {e!r} (known: {', '.join(known)})")
    dup = sorted({e for e in ev.experiments if ev.experiments.count(e) > 1})
    need(not dup, f"'evaluate.experiments' lists {', '.join(map(repr, dup))} more than once (each runs once)")
    for key in ("biased", "randomized", "biased_randomized"):
        need(len(getattr(cfg.evaluate, key).bias_m) == 2, f"'evaluate.{key}.bias_m' must be [x, y]")
    need(len(cfg.study.seeds) >= 1 and len(set(cfg.study.seeds)) == len(cfg.study.seeds),
         "'study.seeds' must list at least one seed, each once")
    need(len(ev.randomized.sigmas_m) >= 1, "'evaluate.randomized.sigmas_m' must list at least one sigma")
    need(len(cfg.evaluate.sensitivity.sigmas_m) >= 1 and min(cfg.evaluate.sensitivity.sigmas_m) >= 0,
         "'evaluate.sensitivity.sigmas_m' must list non-negative values")
    check_simulate(cfg.simulate, where)


def check_simulate(sim: SimulateConfig, where: str = "config") -> None:
    """Cross-key checks of the ``[simulate]`` section."""
    def need(ok: bool, msg: str) -> None:
        if not ok:
            raise ConfigError(f"{where}: {msg}")

    n = SIM_CLASSES
    A = len(sim.view_angles_deg)
    need(A >= 2, "'simulate.view_angles_deg' must list at least two angles")
    need(len(set(sim.view_angles_deg)) == A, "'simulate.view_angles_deg' has repeated angles")
    need(len(sim.view_radii) >= 1 and min(sim.view_radii) > 0,
         "'simulate.view_radii' must list positive radii")
    for c in range(n):
        key = f"scores_class{c + 1}"
        v = getattr(sim, key)
        need(len(v) == n * A,
             f"'simulate.{key}' must hold {n} scores per angle of 'simulate.view_angles_deg' "
             f"({n} x {A} = {n * A} values), got {len(v)}")
        if len(v) != n * A:
            continue  # (raised above)
        sums = [math.fsum(v[i * n:(i + 1) * n]) for i in range(A)]
        bad = [i for i, t in enumerate(sums) if abs(t - 1.0) > 0.05]
        need(not bad, f"'simulate.{key}': the score vector at angle "
             f"{sim.view_angles_deg[bad[0]] if bad else 0:g}° sums to "
             f"{sums[bad[0]] if bad else 1:.3f}, not 1 (scores must be probability-like)")
    need(len(sim.class_names) == n and len(set(sim.class_names)) == n,
         f"'simulate.class_names' must list {n} distinct names")
    need(len(sim.track_start) == 2, "'simulate.track_start' must be [x, y]")
    need(len(set(sim.scenarios)) == len(sim.scenarios) and len(sim.scenarios) >= 1,
         "'simulate.scenarios' must list distinct scenarios")
    for key in ("amplitude_bounds", "length_scale_bounds", "noise_bounds"):
        problem = bounds_problem(getattr(sim, key))
        need(problem is None, f"'simulate.{key}' {problem}")
    need(sim.claim_step < sim.track_steps,
         f"'simulate.claim_step' = {sim.claim_step} must be below 'simulate.track_steps' = {sim.track_steps}")
    for key in ("sweep_noise", "sweep_sigma_max", "sweep_full_noise", "sweep_full_sigma_max"):
        need(len(getattr(sim, key)) >= 1, f"'simulate.{key}' must list at least one value")
    need(sim.example_realization < sim.realizations,
         f"'simulate.example_realization' = {sim.example_realization} must be below "
         f"'simulate.realizations' = {sim.realizations}")
