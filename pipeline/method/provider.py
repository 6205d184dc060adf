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

A provider may also serve a model shaped like the GP bank (the built-in class models with an
instance term are one): ``TrainingViews.fit_bank`` fits the candidate plan's
bank with another fit, ``calibrated`` follows the cell's test-domain variance, ``enabled`` puts it
behind a setting, and ``default_only`` says its models hold for the default model bank only.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping

import numpy as np

from pipeline.infra.config.own import register_sections, unregister_sections
from pipeline.infra.cost import EXTRA_TERMS, FIT_TERMS, register_terms
from pipeline.infra.registry import Registry
from pipeline.infra.outputs import CATALOG

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
    raise about the file. ``fit_bank(fit)``: the GP bank of the same candidate plan, training sets,
    settings and fit cache as the models stage's own, fitted with ``fit`` in place of
    ``pipeline.method.gp_fit.fit_class_models`` (same arguments, plus ``members``: each class's
    member object per training view) -> (the bank, its index extras); for a bank-like model."""
    path: Path
    objects: np.ndarray
    scores: np.ndarray
    passes: Callable[[], dict]
    classes: tuple[str, ...]
    plan: dict
    camera: int
    error: Callable[[str], Exception]
    fit_bank: Callable[[Callable], tuple[Any, dict]] | None = None


@dataclass(frozen=True)
class Spread:
    """Median and quartiles of fitted values (descriptive, not an interval), which the report shows
    as 'median (q25–q75)'; ``of(values)`` skips None and is None for no value."""
    median: float
    q25: float
    q75: float

    @classmethod
    def of(cls, values) -> Spread | None:
        v = np.asarray([x for x in values if x is not None], float)
        if not v.size:
            return None
        q25, q50, q75 = np.percentile(v, [25, 50, 75])
        return cls(float(q50), float(q25), float(q75))


@dataclass(frozen=True)
class Interval:
    """An interval [lo, hi] for the report to show; ``of(pair)`` is None unless it is two numbers."""
    lo: float
    hi: float

    @classmethod
    def of(cls, pair) -> Interval | None:
        return cls(*pair) if isinstance(pair, (list, tuple)) and len(pair) == 2 else None


@dataclass(frozen=True)
class Section:
    """What the report shows of one provider's models (``ModelProvider.section``): a paragraph
    (``text``, a ``str.format`` template whose fields ``values`` fills: the report formats the
    numbers, ``Spread`` and ``Interval`` too; shown as a note unless ``note`` is False), a table
    (``columns``, ``rows`` of values, formatted alike) shown collapsed behind ``collapsed``, its
    ``caption`` and its HTML class ``cls``. With a ``title`` (and ``anchor``) it opens a section of
    the report of its own, which the sections after it in ``ModelProvider.section``'s tuple join;
    without, it is a note of the report's diagnostics section."""
    text: str
    values: dict = field(default_factory=dict)
    columns: tuple[str, ...] = ()
    rows: tuple[tuple, ...] = ()
    caption: str = ""
    collapsed: str = ""
    cls: str = ""
    title: str = ""
    anchor: str = ""
    note: bool = True


class ModelProvider:
    """One kind of model a method needs. ``key`` is the name in the method's ``needs``, the
    folder ``models/<key>/`` and the key of ``TrackInput.models``; the config sections of its
    settings are its own (``sections``), as are their checks (``check``) and its cost (``cost``)."""
    key: ClassVar[str]
    label: ClassVar[str] = ""
    # Its config sections: dotted TOML table -> frozen dataclass of ``setting`` fields, e.g.
    # {"models.<key>": ..., "evaluate.<key>": ...}, read as ``cfg.models.<key>``; loaded, range-checked
    # and hashed into the stage keys like every section (pipeline/infra/config/own.py).
    sections: ClassVar[dict[str, Any]] = {}
    # True: its models are fitted on the default model bank's plan and [models] settings only, so a
    # variant with a bank of its own (a models.* ablation, the contrast's instance arm) runs without
    # them (the methods that need them skip there; evaluate logs it).
    default_only: ClassVar[bool] = False

    def enabled(self, cfg) -> bool:
        """Whether this run fits and loads its models (a provider behind a setting of its own)."""
        return True

    def check(self, cfg, need) -> None:
        """Cross-key checks of its sections, run at config load: ``need(ok, message)`` raises a
        ConfigError naming the file (the message names the keys)."""

    def cost(self, cfg, rows: float) -> list:
        """The evaluate stage's work on these models (``pipeline.infra.cost.Term`` s), ``rows`` being
        the population grid's (cell, realization, step) rows; [] when it is negligible."""
        return []

    def fit_cost(self, cfg, classes: int) -> list:
        """The models stage's work fitting these models for ``classes`` classes
        (``pipeline.infra.cost.Term`` s); [] when it is negligible."""
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

    def calibrated(self, models, variance: np.ndarray):
        """One cell's models under its test-domain variance (``evaluate.test_domain_variance``:
        ``variance``, one δ² per component), for models that share the GP bank's likelihood; the
        models unchanged by default."""
        return models

    def serves(self, models) -> bool:
        """Whether a GP bank handed to ``vf.fuse`` as its ``models`` is also this provider's."""
        return False

    def section(self, index: dict) -> Section | tuple[Section, ...] | None:
        """The report's section (or sections, in order) on the models from their ``index``
        (``models/<key>/index.json``, the file the report reads; None when the provider writes
        none), to which the report adds ``categories``: {class: its category} (a fold class
        '<category>__f<k>''s category, any other class its own)."""
        return None


def register_provider(cls: type[ModelProvider]) -> type[ModelProvider]:
    """Class decorator: add a provider under ``cls.key`` (before the method that needs it)."""
    if not (isinstance(cls, type) and issubclass(cls, ModelProvider)):
        raise TypeError(f"register_provider: cls must be a ModelProvider subclass, got {cls!r:.80}")
    key = getattr(cls, "key", None)
    if not isinstance(key, str) or not key.isidentifier():
        raise ValueError(f"{cls.__name__}: a model provider needs a key that is a name (a folder and a needs "
                         f"entry), got {key!r}")

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
    register_terms(key, inst.cost, module=cls.__module__, fit=inst.fit_cost)
    return cls


def unregister_provider(key: str) -> None:
    PROVIDERS.pop(key, None)
    unregister_sections(key)
    EXTRA_TERMS.remove(key)
    FIT_TERMS.remove(key)


def calibrated(provided: Mapping[str, Any] | None, variance) -> dict:
    """{provider key: models} of one cell under its test-domain variance (None: as they are)."""
    provided = dict(provided or {})
    if variance is None:
        return provided
    v = np.asarray(variance, float)
    return {k: PROVIDERS[k].calibrated(m, v) for k, m in provided.items()}


def known(key: str) -> bool:
    """Whether ``key`` names a registered provider (without loading: for ``register``'s check)."""
    return PROVIDERS.peek(key) is not None


def providers() -> Registry[ModelProvider]:
    return PROVIDERS
