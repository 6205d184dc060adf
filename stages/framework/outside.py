"""Outside code in the cache keys: entries of a registry (``pipeline.infra.registry``) that the
stages' static code key cannot see (an entry point's package, a discovered file, a script's own
registration) enter the key of each stage they change, as ``name=sha256 of its module``. The
stages below them rerun through their upstream digests. The fusion methods are the runner's
``StageSpec.methods`` part; a kind with no outside entry adds nothing, so keys stay as they were."""
from __future__ import annotations

import dataclasses
import importlib
from pipeline.method.registry import registered
from pipeline.infra.datasets import described
from pipeline.scoring.classifiers import UnknownClassifier, classifier

# kind -> (module holding the registry, its attribute, the stages whose output it changes, the
# entries a run uses given its config: None = every registered one)
KINDS = {
    "classifiers": ("pipeline.scoring.classifiers", "REGISTRY", ("classifier",), lambda cfg: {cfg.classifier.arch}),
    "planners": ("pipeline.planning.planners", "PLANNERS", ("evaluate",), lambda cfg: None),
    "metrics": ("pipeline.evaluation.metrics.spec", "METRICS", ("evaluate", "simulate"), lambda cfg: None),
    "datasets": ("pipeline.infra.datasets", "SOURCES", ("data",), lambda cfg: {cfg.data.source}),
    # a method's own model (pipeline.method.provider): fitted by models, loaded and used by evaluate
    "providers": ("pipeline.method.provider", "PROVIDERS", ("models", "evaluate"), lambda cfg: None),
}


def check_loaded(cfg, stage: str, methods: bool) -> None:
    """Refuse ``stage`` (an ``ExtensionError``, one line at the command line) when an entry point of
    a kind it uses does not load (``Registry.failures``): a classifier or dataset source only when the
    config names it, every planner, metric and provider, and the fusion methods for the stages
    that run them. The other stages, ``status`` and ``--help`` run."""
    for kind, (module, attr, stages, used) in KINDS.items():
        if stage in stages:
            getattr(importlib.import_module(module), attr).check_loaded(used(cfg))
    if methods:

        registered().check_loaded()


def outside_parts(cfg, stage: str) -> dict[str, str]:
    """``{kind: fingerprint}`` of the kinds with outside entries that change ``stage`` (a
    classifier only when ``classifier.arch`` names it, a dataset source only when ``data.source``
    does: every planner and metric runs)."""
    out = {}
    for kind, (module, attr, stages, used) in KINDS.items():
        if stage in stages:
            fp = getattr(importlib.import_module(module), attr).outside_fingerprint(used(cfg))
            if fp:
                out[kind] = fp
    return out


def banner(cfg, stage: str, help_text: str) -> str:
    """What the stage's "running" line says: the registered source or classifier the config names
    (its label), not the built-in's words, for the data and classifier stages; else ``help_text``."""
    if stage == "data":

        src = described(cfg.data.source)
        # the config's own data keys: an empty table read as "a run from before the key" (black on both sides)
        data = dataclasses.asdict(cfg.data) if dataclasses.is_dataclass(cfg.data) else {}
        return f"write the data of source '{cfg.data.source}' ({src.describe(data, {})})"
    if stage == "classifier":

        try:
            entry = classifier(cfg.classifier.arch)
        except UnknownClassifier:
            return help_text
        if cfg.classifier.weights == "synthetic" and entry.trains:
            return f"train {entry.label} on the synthetic source domain"
        return f"resolve {entry.label}'s weights (classifier.weights = '{cfg.classifier.weights}')"
    return help_text
