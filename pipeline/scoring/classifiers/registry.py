"""The classifier registry: ``classifier.arch`` names an entry here, and every place that builds,
loads, describes or checks a classifier asks its entry instead of testing the name.

An entry is one ``Classifier`` subclass, registered with ``@register_classifier`` (a plain name,
e.g. ``alexnet``): a module of this package (found by discovery: a new built-in is its file alone),
an entry point of the group ``viewfuse.classifiers`` of an installed package (loaded on first use,
in every process, Ray workers included), or a script's own call; or through a family factory
(``register_family("torchvision", ...)`` serves ``torchvision:<model>``). Entry modules stay light (torch is imported inside their methods), so
checking a config does not load the networks.

An entry declares in its class what the rest of the pipeline needs of it: the card keys that change
a score (``card_fields``, with ``card_extra``), its training footprint (``params``,
``activations_224``), its checks of the ``[classifier]`` section (``config_problems``, ``notes``).
The MC-dropout site is declared by what ``build`` returns: a network with ``trunk(x)`` and
``head_layers()`` (the trunk runs once per crop, the head's Dropout layers are resampled), or
torchvision's ``features -> avgpool -> flatten | classifier`` layout (``pipeline.scoring.mc_dropout``).
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.infra.config.checks import ARCH_NAME
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.footprints import ACT_PER_IMAGE_224, ALEXNET_PARAMS
from pipeline.infra.registry import Registry
from pipeline.infra import extension as X
from pipeline.infra.extension import ExtensionError, declared_key, raise_problems


class UnknownClassifier(ValueError):
    """``classifier.arch`` names no registered entry."""


class Classifier:
    """One classifier architecture. Subclasses set the names and override what differs."""

    key = ""            # the classifier.arch value (the identifying attribute)
    label = ""          # in messages and on the report (default: the key)
    color = "#555555"   # where a figure draws it
    note = ""           # one line on what it is
    name = ""           # the older spellings of ``key`` and ``label``, kept equal to them at registration
    display = ""
    architecture = ""   # the card's "architecture" string (part of the card hash)
    trains = False      # weights = 'synthetic' trains it on the synthetic source domain
    imagenet = False    # weights = 'imagenet' has a local file (never downloaded)
    mc_dropout_site = ""  # where the MC-dropout masks act, in words
    # card keys of this entry's own (from ``card_extra``) that change a score: the card hash, hence
    # the features stage's key, holds them (the common keys are ``pipeline.scoring.card.card_hash``'s)
    card_fields: tuple[str, ...] = ()
    # training's memory footprint (``pipeline.infra.footprints.classifier_training``): parameters,
    # and fp32 activations + gradients per image at 224 px; AlexNet's unless declared
    params = ALEXNET_PARAMS
    activations_224 = ACT_PER_IMAGE_224
    # score with the trunk in channels-last (faster) only where that keeps the scores within 1e-6
    # of the contiguous route's (tests/pipeline/scoring/test_scoring_route.py)
    channels_last_scoring = False

    def build(self, num_classes: int, dropout: float, drop_connect: float = 0.0):
        """A fresh (untrained) network with ``num_classes`` outputs and head dropout p."""
        raise NotImplementedError

    def head_dropout(self, c) -> float:
        """The MC-dropout p this entry reads from the ``[classifier]`` section ``c``."""
        return float(c.dropout)

    def drop_connect(self, c) -> float:
        return 0.0

    def last_linear_key(self) -> str:
        """State-dict key of the last Linear layer's weight (its rows are the classes)."""
        raise NotImplementedError

    def num_classes_of(self, state: dict, path) -> int:
        from pipeline.scoring.weight_files import num_classes_of  # heavy: torch

        return num_classes_of(state, path, key=self.last_linear_key(), what=f"a {self.display}")

    def for_training(self, num_classes: int, dropout: float, seed: int):
        """The network initialised for training on the source domain (entries with ``trains``)."""
        raise NotImplementedError(f"{self.display} is not trained here")

    def early_forward(self):
        """A forward ``f(model, x)`` for the cheap early epochs of training with ``early_head`` =
        "compact" (AlexNet's compact head), or None: the network's own forward."""
        return None

    def imagenet_location(self) -> Path:
        """Where the ImageNet weights file is (it may be missing; raises when not even that is known)."""
        raise NotImplementedError(f"{self.display} has no ImageNet weights file here")

    def imagenet_file(self) -> Path:
        """The ImageNet weights file, checked (missing: WeightsNotFoundError naming what to do)."""
        return self.imagenet_location()

    def output_names(self, n: int) -> list[str]:
        """Names of the ``n`` outputs of the ImageNet weights."""
        return [f"imagenet_{i}" for i in range(n)]

    def config_problems(self, c) -> list[str]:
        """What is wrong with the ``[classifier]`` section ``c`` for this entry (empty: nothing)."""
        return []

    def notes(self, c) -> list[str]:
        """Warnings worth logging for a usable but unusual setting."""
        return []

    def card_extra(self, c) -> dict:
        """Keys the card holds besides the common ones (the arch, so a card rebuilds its network)."""
        out = {"arch": self.name}
        if self.mc_dropout_site:
            out["mc_dropout_site"] = self.mc_dropout_site
        return out

    def describe(self, card: dict) -> str:
        """The report's sentence for weights not trained here."""
        return f"classifier: {self.display} weights from {card.get('weights_file', 'a file')}"


ENTRY_POINT_GROUP = "viewfuse.classifiers"


def _adopt(name: str, obj, module: str) -> None:
    """An entry point naming a Classifier (class or instance) that did not register itself."""
    if isinstance(obj, Classifier) or (isinstance(obj, type) and issubclass(obj, Classifier)):
        register_classifier(obj)
    else:
        raise TypeError(f"entry point {name!r} of {ENTRY_POINT_GROUP!r} names {obj!r}: not a module or a Classifier")


# The built-ins (this package's modules) first, then the others in registration order; the built-in
# folder and the entry points load on first use (the package's __init__ sets ``static``).
REGISTRY: Registry[Classifier] = Registry("classifier", ENTRY_POINT_GROUP, "pipeline.scoring.classifiers",
                                          adopt=_adopt)
_FAMILIES: dict[str, Callable[[str], Classifier]] = {}
_MADE: dict[str, Classifier] = {}   # family members built so far


def problems(entry) -> list[str]:
    """Every breach of the classifier contract (empty: none): a plain key (no ':', families use it),
    text labels, a colour, ``last_linear_key()`` (required), ``build(num_classes, dropout,
    drop_connect)``, and ``for_training(num_classes, dropout, seed)`` when it ``trains``."""

    inst = entry
    if isinstance(entry, type):
        if not issubclass(entry, Classifier):
            return [f"{entry!r:.60} is not a Classifier"]
        inst = entry.__new__(entry)     # the class's declarations, without running an __init__
    elif not isinstance(entry, Classifier):
        return [f"{entry!r:.60} is not a Classifier"]
    key, cls = X.declared_key(inst), type(inst)
    out = [None if ARCH_NAME.fullmatch(key or "") and ":" not in key else
           f"classifier key {key!r:.60}: letters, digits and '_.-', no ':' (families use it)",
           X.plain_name_problem(key) if key else None]
    for attr in ("label", "display", "note"):
        out.append(X.text_problem(attr, getattr(inst, attr, "")))
    out.append(X.color_problem(getattr(inst, "color", None)))
    if cls.last_linear_key is Classifier.last_linear_key:
        out.append("last_linear_key() is required (the state-dict key of the last Linear layer's weight)")
    else:
        out.append(X.signature_problem(cls.last_linear_key, "last_linear_key", "last_linear_key()", inst))
    if cls.build is Classifier.build:
        out.append("build(num_classes, dropout, drop_connect=0.0) is not implemented")
    else:
        out.append(X.signature_problem(cls.build, "build", "build(num_classes, dropout, drop_connect)",
                                       inst, 3, 0.5, 0.0))
    if getattr(inst, "trains", False):
        if cls.for_training is Classifier.for_training:
            out.append("trains = True needs for_training(num_classes, dropout, seed)")
        else:
            out.append(X.signature_problem(cls.for_training, "for_training", "for_training(num_classes, dropout, seed)",
                                           inst, 3, 0.5, 0))
    return [p for p in out if p]


def register_classifier(entry):
    """Register a ``Classifier`` subclass (usable as a class decorator) or instance under its key;
    every breach of the contract (``problems``) is one ``ExtensionError`` naming it."""

    key = declared_key(entry) if isinstance(entry, (type, Classifier)) else ""
    raise_problems("classifier", key or repr(entry)[:60], "register", problems(entry))
    inst = entry() if isinstance(entry, type) else entry
    inst.key = inst.name = key
    inst.label = inst.display = inst.label or inst.display or key
    old = REGISTRY.peek(key)
    if old is not None and type(old) is not type(inst):
        raise ExtensionError.of("classifier", key, "register", f"already registered ({type(old).__name__})")
    REGISTRY.add(key, inst, module=type(inst).__module__, replace=True)
    return entry


def unregister_classifier(name: str) -> None:
    """Remove an entry (tests that register a toy one clean up after themselves)."""
    REGISTRY.remove(name)


def register_family(prefix: str, factory: Callable[[str], Classifier]) -> None:
    """Serve ``<prefix>:<model>`` names with ``factory(model)`` (raises UnknownClassifier for a bad model)."""
    _FAMILIES[prefix] = factory


def names() -> list[str]:
    """Registered names, the built-ins first, then the families as ``<prefix>:<model>``, then the
    entries registered from outside (an entry point, a script) in registration order."""
    builtin = [n for n in REGISTRY if REGISTRY.is_builtin(n)]
    return builtin + [f"{p}:<model>" for p in sorted(_FAMILIES)] + [n for n in REGISTRY if not REGISTRY.is_builtin(n)]


def classifier(arch: str) -> Classifier:
    """The entry ``arch`` names, or UnknownClassifier listing the registered ones."""
    if arch in REGISTRY:
        return REGISTRY[arch]
    if arch in _MADE:
        return _MADE[arch]
    prefix, sep, model = str(arch).partition(":")
    if sep and prefix in _FAMILIES:
        entry = _FAMILIES[prefix](model)
        _MADE[arch] = entry
        return entry
    raise UnknownClassifier(f"unknown classifier architecture {arch!r} (one of {', '.join(names())})")


def check_config(c, where: str) -> None:
    """The registry's checks of the ``[classifier]`` section ``c``: ConfigError naming the file and key."""
    try:
        entry = classifier(c.arch)
    except UnknownClassifier as e:
        raise ConfigError(f"{where}: 'classifier.arch': {e}") from None
    problems = list(entry.config_problems(c))
    if c.weights == "synthetic" and not entry.trains:
        problems.append(f"'classifier.arch' = {c.arch!r} trains nothing: set 'classifier.weights' = "
                        + ("'imagenet' or 'path'" if entry.imagenet else "'path' (a state-dict file)"))
    if c.weights == "imagenet" and not entry.imagenet:
        problems.append(f"'classifier.arch' = {c.arch!r} has no local ImageNet weights: set 'classifier.weights' "
                        "= 'path' and 'classifier.path' to a state-dict file")
    if problems:
        raise ConfigError(f"{where}: " + "; ".join(problems))


def card_arch(card: dict) -> str:
    """The card's ``classifier.arch`` (cards written before the key existed are AlexNet's)."""
    return str(card.get("arch", "alexnet"))


def describe_card(card: dict) -> str | None:
    """The card's entry's sentence for weights not trained here, or None when its arch is not registered."""
    try:
        return classifier(card_arch(card)).describe(card)
    except UnknownClassifier:
        return None


def display_of(card: dict) -> str:
    """The card's network in words (its architecture string when the arch is not registered here)."""
    try:
        return classifier(card_arch(card)).display
    except UnknownClassifier:
        return str(card.get("architecture", "a network"))
