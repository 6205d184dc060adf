"""What a fusion method is (``FusionMethod``, the ``TrackInput`` it reads) and how it registers
(``register``). The method files import this module only; ``pipeline.method.registry`` loads the
built-ins and entry points and answers which methods there are (so the two never import each other)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, ClassVar, Mapping

import numpy as np

from pipeline.infra.registry import Registry
from pipeline.method import provider as _provider
from pipeline.infra import extension as X
from pipeline.infra.extension import ExtensionError, raise_problems

# What the cell carries itself; a method may also need the models of a registered provider
# (``pipeline.method.provider``: ``TrackInput.models``).
NEEDS = frozenset({"gp", "scores", "probs"})
ENTRY_POINT_GROUP = "viewfuse.methods"
# The method every other (non-attribution) method is paired against in the population.
REFERENCE = "with_uncertainty"


@dataclass(frozen=True)
class TrackInput:
    """What a method may read to fuse one track. ``R`` realizations of pose estimates share the
    track's scores; arrays a cell does not carry are None (a method whose ``needs`` miss is skipped).

    ``estimates`` (R, K, 2) and ``samples`` (R, N_x, K, 2) are ground-frame positions; ``inputs``
    maps positions (..., 2) to the GP inputs (unit circle, object frame). ``rng`` is the track's own
    stream for methods that draw (each method its own, keyed by its key: seeded by the cell's identity,
    and for a pose-using method by the setting). ``models``: each provider's models of the candidates
    ({provider key: models}, ``pipeline.method.provider``)."""
    dropout: np.ndarray                    # (K, N_s, F) MC-dropout scores of the GP components
    gp: object | None = None               # GPClassModels of the candidates
    own: np.ndarray | None = None          # (K, N_s, C) each candidate's own score
    probs: np.ndarray | None = None        # (K, N_s, D) whole probability vectors
    estimates: np.ndarray | None = None    # (R, K, 2)
    samples: np.ndarray | None = None      # (R, N_x, K, 2)
    inputs: Callable[[np.ndarray], np.ndarray] | None = None
    var_floor: float = 1e-6
    rng: np.random.Generator | None = None
    threads: int | None = None             # engine threads (speed only); planning's workers use 1
    models: Mapping[str, object] = field(default_factory=dict)

    @property
    def measurement(self) -> np.ndarray:
        """One measurement per step: the mean of the dropout samples (K, F)."""
        return self.dropout.mean(axis=1)

    def has(self, need: str) -> bool:
        own = {"gp": self.gp, "scores": self.own, "probs": self.probs}
        return (own[need] if need in own else self.models.get(need)) is not None


class FusionMethod:
    """One fusion method. Subclasses set the class attributes and implement ``fuse``."""
    key: ClassVar[str]                 # stored in every results row and summary.json
    label: ClassVar[str]               # display name (tables, legends); default: the key
    short: ClassVar[str]               # short display name; default: the label
    color: ClassVar[str] = "#555555"   # figures' colour
    note: ClassVar[str] = ""           # one line for the report's method table
    needs: ClassVar[frozenset] = frozenset({"gp"})
    uses_poses: ClassVar[bool] = True
    uses_dropout: ClassVar[bool] = True
    simulation: ClassVar[bool] = False      # also fused in the §5.3 simulation (``simulate``)
    planning: ClassVar[bool] = False        # view planning's belief update may use it (``fuse_tracks``)
    attribution: ClassVar[bool] = False     # an ingredient variant: runs only with evaluate.attribution

    def applies(self, t: TrackInput) -> bool:
        return all(t.has(n) for n in self.needs)

    def fuse(self, t: TrackInput) -> np.ndarray:
        """Log posteriors after every step: (R, K, C) for a pose-using method, (K, C) for a
        pose-free one (repeated over the realizations by the caller)."""
        raise NotImplementedError

    def fuse_with_extras(self, t: TrackInput) -> tuple[np.ndarray, dict]:
        """``fuse`` plus what the method reports beside its posterior (kept per cell, e.g. a
        spread); a pose-free method is fused through this once per track."""
        return self.fuse(t), {}

    def population_block(self, cfg, pairs: list) -> dict | None:
        """summary.json's block under the method's key (beside the population's), from ``pairs``:
        (cell, the extras ``fuse_with_extras`` returned there, plus ``posterior0``: the posterior
        (K, C) of the cell's first setting, realization 0) over the default variant's cells; None =
        no block."""
        return None

    def report_note(self, block: dict | None) -> tuple[str, dict]:
        """The report's note on the method beside the paired comparisons, from its summary.json
        block (``population_block``): a ``str.format`` template and the values it names (the
        report formats the numbers); ("", {}) = none."""
        return "", {}

    def single_view(self, t: TrackInput) -> np.ndarray | None:
        """Each view alone at the true pose (``t.estimates`` (1, K, 2) true positions): log
        posteriors (K, C), or None when the method has no single-view reading."""
        return None

    def fuse_tracks(self, t: TrackInput) -> np.ndarray:
        """View planning's belief update (``planning = True``): R tracks of equal length, each with
        its own views, so ``t.dropout`` is (R, K, N_s, F) beside ``t.samples`` (R, N_x, K, 2) and
        ``t.estimates`` (R, K, 2) -> log posteriors (R, K, C)."""
        raise NotImplementedError

    def simulate(self, models, draws, sim) -> np.ndarray:
        """The §5.3 simulation (``simulation = True``): posteriors (R, K, C), probabilities, from
        ``draws`` (``pipeline.evaluation.simulation.scenarios.Draws``) and the section ``sim``."""
        raise NotImplementedError


def _adopt(name: str, obj, module: str) -> None:
    """An entry point naming a FusionMethod subclass that did not register itself."""
    if isinstance(obj, type) and issubclass(obj, FusionMethod):
        register(obj)
    else:
        raise TypeError(f"entry point {name!r} of {ENTRY_POINT_GROUP!r} names {obj!r}: not a module or a FusionMethod")


# Built-ins first (``pipeline.method.methods``, in their registration order), then the others in
# theirs, whatever was imported first; loads the built-ins and entry points on first use.
_REGISTRY: Registry[FusionMethod] = Registry("fusion method", ENTRY_POINT_GROUP, "pipeline.method.methods",
                                             adopt=_adopt)


def problems(cls) -> list[str]:
    """Every breach of the method contract ``cls`` declares (empty: none): a plain key without
    '-', text labels, a colour matplotlib can draw, ``needs`` a set of known names, the hooks its
    flags promise, and ``fuse(t)`` (and the others it overrides) callable with one track input."""

    out = []
    key = getattr(cls, "key", None)
    if not isinstance(key, str) or not key or "-" in key:
        out.append(f"a fusion method needs a non-empty key without '-' (comparison keys join two with '-'), "
                   f"got {key!r:.60}")
    else:
        out.append(X.plain_name_problem(key))
    for attr in ("label", "short"):     # default: the key, the label
        out.append(X.text_problem(attr, getattr(cls, attr, None) or "x"))
    out.append(X.text_problem("note", getattr(cls, "note", None)))
    out.append(X.color_problem(getattr(cls, "color", None)))
    needs = getattr(cls, "needs", None)
    if isinstance(needs, str) or not isinstance(needs, (set, frozenset, tuple, list)) or \
            not all(isinstance(n, str) for n in needs):
        out.append(f"needs must be a set of names (of {sorted(NEEDS)}), got {needs!r:.80}")
    else:
        bad = {n for n in needs if n not in NEEDS and not _provider.known(n)}
        if bad:
            out.append(f"unknown needs {sorted(bad)} (known: {sorted(NEEDS)} and the registered model providers; "
                       "register a method's provider before the method)")
    for flag, hook in (("simulation", "simulate"), ("planning", "fuse_tracks")):
        if getattr(cls, flag) and getattr(cls, hook) is getattr(FusionMethod, hook):
            out.append(f"{flag} = True needs {hook}() (optional otherwise)")
    for hook, args, call in (("fuse", 1, "fuse(t)"), ("single_view", 1, "single_view(t)"),
                             ("fuse_with_extras", 1, "fuse_with_extras(t)"), ("fuse_tracks", 1, "fuse_tracks(t)"),
                             ("simulate", 3, "simulate(models, draws, sim)"),
                             ("population_block", 2, "population_block(cfg, pairs)"),
                             ("report_note", 1, "report_note(block)")):
        fn = getattr(cls, hook, None)
        if fn is not getattr(FusionMethod, hook):
            out.append(X.signature_problem(fn, hook, call, None, *([None] * args)))
    return [p for p in out if p]


def register(cls: type[FusionMethod]) -> type[FusionMethod]:
    """Class decorator: add a method under ``cls.key`` (a key registered twice is an error). Every
    breach of the contract (``problems``) is one ``ExtensionError`` naming the method."""

    if not (isinstance(cls, type) and issubclass(cls, FusionMethod)):
        raise ExtensionError.of("fusion method", getattr(cls, "key", repr(cls)[:60]), "register",
                                f"register: cls must be a FusionMethod subclass, got {cls!r:.80}")
    key = getattr(cls, "key", None)
    raise_problems("fusion method", key if isinstance(key, str) else cls.__name__, "register", problems(cls))
    old = _REGISTRY.peek(key)
    if old is not None and type(old) is not cls:
        raise ExtensionError.of("fusion method", key, "register",
                                f"registered twice ({type(old).__name__}, {cls.__name__})")
    cls.label = getattr(cls, "label", None) or key
    cls.short = getattr(cls, "short", None) or cls.label
    _REGISTRY.add(key, cls(), module=cls.__module__, replace=True)
    return cls


def unregister(key: str) -> None:
    """Remove a method (tests that register a toy one clean up after themselves)."""
    if not isinstance(key, str):
        raise TypeError(f"unregister: key must be a method key (str), got {type(key).__name__}")
    _REGISTRY.pop(key, None)


def registered() -> Registry[FusionMethod]:
    """The registered methods by key: the built-ins first, then the others, each in registration
    order (using it loads the built-ins and the entry points)."""
    return _REGISTRY
