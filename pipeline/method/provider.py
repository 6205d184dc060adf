"""A method's own model (``ModelProvider``): what a fusion method that needs more than the GP bank
declares so that the stages fit, save, load and report that model without knowing it.

The ``models`` stage fits every provider that a registered method names in its ``needs``
(``fit`` on the BigBIRD training views, ``TrainingViews``) and writes it to ``models/<key>/``
(``save``); ``evaluate`` loads it (``load``), narrows it to each cell's candidates (``for_cell``)
and hands it to the method as ``TrackInput.models[key]``. ``digest`` goes into the models stage's
summary (the evaluate stage's key follows the models folder's content); the provider's module,
when it comes from outside the project, enters the keys of ``models`` and ``evaluate``
(``stages/framework/outside.py``). ``summary`` is the models stage's one line about it, ``section``
what the report shows of its index. Providers register with ``@register_provider`` in the same
module as (or one imported by) the method that needs them, so the method's entry point brings both.
Its config sections (``sections``), their checks (``check``) and its cost terms (``cost``) go to the
infra floor's registries (``pipeline.infra.config.own``, ``pipeline.infra.cost``), which load the
methods' package and entry points before a config is parsed, in every process.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np

from pipeline.infra.config.own import register_sections, unregister_sections
from pipeline.infra.cost import EXTRA_TERMS, register_terms
from pipeline.infra.registry import Registry

# Built-ins register from the method files (``pipeline.method.methods``); outside providers come
# with their method's entry point (the same group).
PROVIDERS: Registry["ModelProvider"] = Registry("model provider", "viewfuse.methods", "pipeline.method.methods")


@dataclass(frozen=True)
class TrainingViews:
    """The training ring's views as the ``models`` stage read them from features/bigbird.parquet
    (``path``, named in every error): ``objects`` (N,) each view's class, ``scores`` (N, D) its
    deterministic pass, ``passes()`` the MC-dropout passes {class: {angle: (S, D)}} (read on first
    call: a provider that needs none pays nothing), ``classes`` the modelled classes and ``plan``
    the candidate sets {target: {"classes", "components"}}; ``error(problem)`` the exception to
    raise about the file."""
    path: Path
    objects: np.ndarray
    scores: np.ndarray
    passes: Callable[[], dict]
    classes: tuple[str, ...]
    plan: dict
    camera: int
    error: Callable[[str], Exception]


@dataclass(frozen=True)
class Section:
    """What the report shows of one provider's models (``ModelProvider.section``): a paragraph
    (``text``, a ``str.format`` template whose fields ``values`` fills: the report formats the
    numbers), a table (``columns``, ``rows`` of values, numbers formatted by the report) shown
    collapsed behind ``collapsed``, its ``caption`` and its HTML class ``cls``."""
    text: str
    values: dict = field(default_factory=dict)
    columns: tuple[str, ...] = ()
    rows: tuple[tuple, ...] = ()
    caption: str = ""
    collapsed: str = ""
    cls: str = ""


class ModelProvider:
    """One kind of model a method needs. ``key`` is the name in the method's ``needs``, the
    folder ``models/<key>/`` and the key of ``TrackInput.models``; the config sections of its
    settings are its own (``sections``), as are their checks (``check``) and its cost (``cost``)."""
    key: ClassVar[str]
    label: ClassVar[str] = ""
    # Its config sections: dotted TOML table -> frozen dataclass of ``setting`` fields, e.g.
    # {"models.<key>": ..., "evaluate.<key>": ...}, read as ``cfg.models.<key>``; loaded, range-checked
    # and hashed into the stage keys like every section (pipeline/infra/config/own.py).
    sections: ClassVar[dict[str, type]] = {}

    def check(self, cfg, need) -> None:
        """Cross-key checks of its sections, run at config load: ``need(ok, message)`` raises a
        ConfigError naming the file (the message names the keys)."""

    def cost(self, cfg, rows: float) -> list:
        """The evaluate stage's work on these models (``pipeline.infra.cost.Term`` s), ``rows`` being
        the population grid's (cell, realization, step) rows; [] when it is negligible."""
        return []

    def fit(self, views: TrainingViews, cfg) -> tuple[Any, dict]:
        """(the models, the extras written beside them in their index)."""
        raise NotImplementedError

    def save(self, models, folder: Path, extra: dict) -> None:
        raise NotImplementedError

    def load(self, folder: Path, cfg):
        """The saved models, with any evaluate-time settings of ``cfg`` they carry."""
        raise NotImplementedError

    def digest(self, models) -> str:
        """Changes whenever the models do (the models stage records it)."""
        raise NotImplementedError

    def record(self, models, extra: dict) -> dict:
        """Numbers the models stage keeps in its record (as ``<key>_<name>``)."""
        return {}

    def summary(self, models, extra: dict, cfg) -> str:
        """The models stage's clause about these models (its one-line summary)."""
        return f"{self.key} models"

    def for_cell(self, models, target: str, classes: tuple[str, ...], dim: int):
        """The models of one cell's candidates ``classes`` (target ``target``); ``dim``: entries of
        the cell's score vectors. A mismatch is a ValueError."""
        return models

    def section(self, index: dict) -> Section | None:
        """The report's section on the models from their ``index`` (``models/<key>/index.json``, the
        file the report reads; None when the provider writes none)."""
        return None


def register_provider(cls: type[ModelProvider]) -> type[ModelProvider]:
    """Class decorator: add a provider under ``cls.key`` (before the method that needs it)."""
    if not (isinstance(cls, type) and issubclass(cls, ModelProvider)):
        raise TypeError(f"register_provider: cls must be a ModelProvider subclass, got {cls!r:.80}")
    key = getattr(cls, "key", None)
    if not isinstance(key, str) or not key.isidentifier():
        raise ValueError(f"{cls.__name__}: a model provider needs a key that is a name (a folder and a needs "
                         f"entry), got {key!r}")
    from pipeline.infra.outputs import CATALOG

    taken = {a.name for a in CATALOG["models"].values() if not a.pattern}
    if key in taken:   # its folder models/<key>/ would be another output's
        raise ValueError(f"{cls.__name__}: a model provider's key names its folder under models/, and "
                         f"{key!r} is taken ({', '.join(sorted(taken))})")
    old = PROVIDERS.peek(key)
    if old is not None and type(old).__qualname__ != cls.__qualname__:
        raise ValueError(f"model provider {key!r} is registered twice ({type(old).__name__}, {cls.__name__})")
    inst = PROVIDERS.add(key, cls(), module=cls.__module__, replace=True)
    # the infra floor's hooks (it never imports the method): config sections and the cost model
    register_sections(key, cls.sections, check=inst.check, module=cls.__module__)
    register_terms(key, inst.cost, module=cls.__module__)
    return cls


def unregister_provider(key: str) -> None:
    PROVIDERS.pop(key, None)
    unregister_sections(key)
    EXTRA_TERMS.remove(key)


def known(key: str) -> bool:
    """Whether ``key`` names a registered provider (without loading: for ``register``'s check)."""
    return PROVIDERS.peek(key) is not None


def providers() -> Registry[ModelProvider]:
    return PROVIDERS
