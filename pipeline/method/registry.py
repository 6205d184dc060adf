"""The fusion-method registry: every method the evaluation compares is one ``FusionMethod``
subclass, registered with ``@register``. The population grid, the single-track experiments, the
simulation, ``summary.json``, the report and ``compare`` iterate ``methods()``; nothing else names
a method to run it.

A method declares what it reads (``needs``: ``"gp"`` the candidates' GP bank, ``"scores"`` each
candidate's own score, ``"probs"`` the whole probability vectors, or the key of a model provider,
``pipeline.method.provider``, whose models the models stage fits for it), whether it uses the pose samples (``uses_poses``; a pose-free method is fused once per
track and its posterior repeated over the realizations, so the methods pair up realization by
realization) and the dropout samples, and fuses one track batched over realizations (``fuse``).

The built-in methods live in ``pipeline.method.methods`` (one file each); other packages add
theirs through the entry-point group ``viewfuse.methods`` (each entry point names a module or a
class; importing it registers). The order of tables, figures and rows is the built-ins' order,
then the other methods in registration order, whatever was imported first (``pipeline.infra.registry``).
"""
from __future__ import annotations

from pipeline.method.method_base import (ENTRY_POINT_GROUP, NEEDS, REFERENCE, FusionMethod,  # noqa: F401 - public here
                                         TrackInput, register, registered, unregister)
from pipeline.method.provider import ModelProvider, providers


def _load() -> None:
    """The built-ins (their listed modules are in the stages' code key already), the folder's other
    modules and the entry points of ``viewfuse.methods``: once per process, on first use."""
    from pipeline.method.methods import LISTED  # heavy: scipy

    registered().static = frozenset(f"pipeline.method.methods.{n}" for n in LISTED)
    registered().load()


def methods(*, attribution: bool = True) -> list[FusionMethod]:
    """Every registered method, the built-ins first (without the attribution variants when
    ``attribution`` is False)."""
    _load()
    return [m for m in registered().values() if attribution or not m.attribution]


def keys(*, attribution: bool = False) -> tuple[str, ...]:
    return tuple(m.key for m in methods(attribution=attribution))


def get(key: str) -> FusionMethod | None:
    _load()
    return registered().get(key)


def comparisons() -> tuple[tuple[str, str], ...]:
    """The population's paired comparisons: the reference method against every other method."""
    return tuple((REFERENCE, k) for k in keys() if k != REFERENCE)


def outside_fingerprint() -> str:
    """The methods registered from outside the listed built-ins (a discovered built-in file, an
    entry point, a test), each as ``key=sha256 of its module's source``: the evaluate and simulate
    stages add it to their cache key, so registering, removing or editing such a method reruns them
    (the built-ins are in their code key already)."""
    _load()
    return registered().outside_fingerprint()


def model_providers(cfg=None) -> list[ModelProvider]:
    """The providers the registered methods need (``needs`` naming one), each once, in method order:
    what the models stage fits and evaluate loads (with ``cfg``, those it enables:
    ``ModelProvider.enabled``)."""
    _load()
    out: dict[str, ModelProvider] = {}
    for m in methods():
        for n in sorted(m.needs):
            if n in providers() and n not in out and (cfg is None or providers()[n].enabled(cfg)):
                out[n] = providers()[n]
    return list(out.values())


def providers_fingerprint() -> str:
    """Like ``outside_fingerprint``, for the providers the methods need: their source enters the
    keys of the models and evaluate stages."""
    _load()
    return providers().outside_fingerprint({p.key for p in model_providers()})
