"""The fusion-method registry: every method the evaluation compares is one ``FusionMethod``
subclass, registered with ``@register``. The population grid, the single-track experiments, the
simulation, ``summary.json``, the report and ``compare`` iterate ``methods()``; nothing else names
a method to run it.

A method declares what it reads (``needs``: ``"gp"`` the candidates' GP bank, ``"dirichlet"`` their
Dirichlet models, ``"scores"`` each candidate's own score, ``"probs"`` the whole probability
vectors), whether it uses the pose samples (``uses_poses``; a pose-free method is fused once per
track and its posterior repeated over the realizations, so the methods pair up realization by
realization) and the dropout samples, and fuses one track batched over realizations (``fuse``).

The built-in methods live in ``pipeline.method.methods`` (one file each); other packages add
theirs through the entry-point group ``viewfuse.methods`` (each entry point names a module or a
class; importing it registers). Registration order is the order of tables, figures and rows.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np

NEEDS = frozenset({"gp", "dirichlet", "scores", "probs"})
ENTRY_POINT_GROUP = "viewfuse.methods"
# The method every other (non-attribution) method is paired against in the population.
REFERENCE = "with_uncertainty"


@dataclass(frozen=True)
class TrackInput:
    """What a method may read to fuse one track. ``R`` realizations of pose estimates share the
    track's scores; arrays a cell does not carry are None (a method whose ``needs`` miss is skipped).

    ``estimates`` (R, K, 2) and ``samples`` (R, N_x, K, 2) are ground-frame positions; ``inputs``
    maps positions (..., 2) to the GP inputs (unit circle, object frame). ``rng`` is the track's own
    stream for methods that draw (seeded by the cell's identity, not by the setting)."""
    dropout: np.ndarray                    # (K, N_s, F) MC-dropout scores of the GP components
    gp: object | None = None               # GPClassModels of the candidates
    dirichlet: object | None = None        # DirichletModels of the candidates
    own: np.ndarray | None = None          # (K, N_s, C) each candidate's own score
    probs: np.ndarray | None = None        # (K, N_s, D) whole probability vectors
    estimates: np.ndarray | None = None    # (R, K, 2)
    samples: np.ndarray | None = None      # (R, N_x, K, 2)
    inputs: Callable[[np.ndarray], np.ndarray] | None = None
    var_floor: float = 1e-6
    n_ss: int = 100                        # Dirichlet cloud size (evaluate.dirichlet.n_ss)
    rng: np.random.Generator | None = None

    @property
    def measurement(self) -> np.ndarray:
        """One measurement per step: the mean of the dropout samples (K, F)."""
        return self.dropout.mean(axis=1)

    def has(self, need: str) -> bool:
        return {"gp": self.gp, "dirichlet": self.dirichlet, "scores": self.own, "probs": self.probs}[need] is not None


class FusionMethod:
    """One fusion method. Subclasses set the class attributes and implement ``fuse``."""
    key: ClassVar[str]                 # stored in every results row and summary.json
    label: ClassVar[str]               # display name (tables, legends)
    short: ClassVar[str]               # short display name
    color: ClassVar[str] = "#555555"   # figures' colour
    note: ClassVar[str] = ""           # one line for the report's method table
    needs: ClassVar[frozenset] = frozenset({"gp"})
    uses_poses: ClassVar[bool] = True
    uses_dropout: ClassVar[bool] = True
    simulation: ClassVar[bool] = False      # also fused in the §5.3 simulation (``simulate``)
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

    def single_view(self, t: TrackInput) -> np.ndarray | None:
        """Each view alone at the true pose (``t.estimates`` (1, K, 2) true positions): log
        posteriors (K, C), or None when the method has no single-view reading."""
        return None

    def simulate(self, models, draws, sim) -> np.ndarray:
        """The §5.3 simulation (``simulation = True``): posteriors (R, K, C), probabilities, from
        ``draws`` (``pipeline.evaluation.simulation.scenarios.Draws``) and the section ``sim``."""
        raise NotImplementedError


_REGISTRY: dict[str, FusionMethod] = {}
_LOADED = False


def register(cls: type[FusionMethod]) -> type[FusionMethod]:
    """Class decorator: add a method under ``cls.key`` (a key registered twice is an error)."""
    key = getattr(cls, "key", None)
    if not isinstance(key, str) or not key or "-" in key:
        raise ValueError(f"{cls.__name__}: a fusion method needs a non-empty key without '-' (comparison keys "
                         f"join two with '-'), got {key!r}")
    bad = set(cls.needs) - NEEDS
    if bad:
        raise ValueError(f"{cls.__name__}: unknown needs {sorted(bad)} (known: {sorted(NEEDS)})")
    if key in _REGISTRY and type(_REGISTRY[key]) is not cls:
        raise ValueError(f"fusion method {key!r} is registered twice ({type(_REGISTRY[key]).__name__}, {cls.__name__})")
    _REGISTRY[key] = cls()
    return cls


def unregister(key: str) -> None:
    """Remove a method (tests that register a toy one clean up after themselves)."""
    _REGISTRY.pop(key, None)


def _load() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    import pipeline.method.methods  # noqa: F401  (the built-ins register on import, in order)
    from importlib.metadata import entry_points
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        ep.load()


def methods(*, attribution: bool = True) -> list[FusionMethod]:
    """Every registered method in registration order (without the attribution variants when
    ``attribution`` is False)."""
    _load()
    return [m for m in _REGISTRY.values() if attribution or not m.attribution]


def keys(*, attribution: bool = False) -> tuple[str, ...]:
    return tuple(m.key for m in methods(attribution=attribution))


def get(key: str) -> FusionMethod | None:
    _load()
    return _REGISTRY.get(key)


def comparisons() -> tuple[tuple[str, str], ...]:
    """The population's paired comparisons: the reference method against every other method."""
    return tuple((REFERENCE, k) for k in keys() if k != REFERENCE)


def _listed() -> tuple[str, ...]:
    from pipeline.method.methods import LISTED
    return LISTED


def outside_fingerprint() -> str:
    """The methods registered from outside the listed built-ins (a discovered built-in file, an
    entry point, a test), each as ``key=sha256 of its module's source``: the evaluate and simulate stages add it to their cache key, so registering,
    removing or editing such a method reruns them (the built-ins are in their code key already)."""
    import hashlib
    import inspect

    parts = []
    for m in methods():
        cls = type(m)
        if cls.__module__.rpartition(".")[::2] in (("pipeline.method.methods", n) for n in _listed()):
            continue
        try:
            src = inspect.getsource(inspect.getmodule(cls))
        except (OSError, TypeError):   # defined interactively: the class's own attributes stand in
            src = repr(sorted((k, repr(v)) for k, v in vars(cls).items()))
        parts.append(f"{m.key}={hashlib.sha256(src.encode()).hexdigest()[:16]}")
    return ";".join(parts)

