"""Dataset sources: what ``data.source`` names. A source is one ``DatasetSource`` in the registry
(``pipeline.infra.registry``): the built-ins of ``loaders/sources/`` (a new file there registers),
then ``vf.register_dataset`` calls and the ``viewfuse.datasets`` entry points of installed packages.

A source declares its config (``config``: the dataclass of its own ``[data.<name>]`` section, read
and range-checked by the loader like every section; ``check``: its cross-key checks), what it gives
the models stage (``classes``), and the data stage's work (``write``: its reader and how it writes
the BigBIRD/AVD-format run data under the stage folder, or, with ``writes = False``, a check of
roots read in place), and how much of it there will be (``work``: the views and crops it writes,
from its config, for the cost model ``pipeline.infra.cost``). Config validation asks the registry:
an unknown name is an error listing the registered ones.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.infra.errors import ConfigError
from pipeline.infra.registry import Registry
from pipeline.infra import extension as X
from pipeline.infra.extension import declared_key, raise_problems

ENTRY_POINT_GROUP = "viewfuse.datasets"
BUILTIN = "loaders.sources"
# The built-in sources' modules: the data stage imports them by name, so its code key covers them
# and everything they import; any other source enters the key through stages/framework/outside.py.
STATIC = tuple(f"{BUILTIN}.{m}" for m in ("synthetic", "real", "real_imagery"))


# AVD boxes a real scan holds, on average over the 15 scans of ../shared/realdata/avd (annotations.json),
# at difficulty <= 1..5: what frames = 'all' (every box of a located instance) and the real source's
# scoring reach at most.
AVD_BOXES_PER_SCAN = {1: 87, 2: 288, 3: 1112, 4: 2226, 5: 3322}
# Frames a scan gets with frames = 'viewpoints' (per grid point the view facing a located instance
# best), measured: real_full 12,440 AVD crops on 15 scans (COIL) and real_category 3,801 on 3 scans
# (ETH-80), docs/results.md. Scans differ by about 2x (their located instances): a typical figure.
VIEWPOINT_FRAMES_PER_SCAN = (12_440 + 3_801) // (15 + 3)


@dataclass(frozen=True)
class Work:
    """What a source's data stage writes and the features stage scores, from its config alone (the
    counts ``pipeline.infra.cost`` turns into seconds). None: not known before the data exists (the
    cost model logs "not estimated"; the features stage checks again with the boxes it finds)."""
    training_views: int | None          # BigBIRD views written (or read in place) and scored
    test_crops: int | None              # AVD boxes the features stage scores
    view_keys: tuple[str, ...] = ()     # the settings that multiply each count
    crop_keys: tuple[str, ...] = ()
    data_keys: tuple[str, ...] = ()     # settings that multiply the data stage's rendering (or its writing, with those)
    written: int = 0                    # images the data stage decodes, pastes and encodes (0: none)
    rendered_megapixels: float = 0.0    # pixels the data stage renders (synthetic stand-ins)
    render_workers: int = 1
    # the training views one class model is fitted on (one camera's ring; a category's, all its
    # members'): the models stage's GP fits grow with its cube. None: BigBIRD's 120 angles
    views_per_class: float | None = None


def frames_per_scan(frames: str, max_difficulty: int) -> int:
    """Typical frames (crops) the scan writer gives one real AVD scan (``frames``: 'viewpoints' | 'all')."""
    boxes = AVD_BOXES_PER_SCAN[max(1, min(5, int(max_difficulty)))]
    return boxes if frames == "all" else min(VIEWPOINT_FRAMES_PER_SCAN, boxes)


class DatasetSource:
    """One value of ``data.source``. Subclass, set ``name`` (and ``config`` for keys of your own),
    implement ``write``; register with ``@vf.register_dataset``."""

    key: str = ""                # the data.source value (the identifying attribute)
    # (hook, how it is called, its arguments): what a source must implement itself
    required_hooks: tuple = (("write", "write(ctx)", 1),)
    name: str = ""               # its older spelling, kept equal to it at registration
    doc: str = ""
    color: str = "#555555"       # where a figure draws it
    note: str = ""               # one line on what it is
    config: type | None = None   # a frozen dataclass of ``setting`` fields: the [data.<name>] section
    writes: bool = True          # False: the BigBIRD/AVD roots are read in place (data.bigbird_root, avd_root)
    # What the report says of the data, so that a source of its own gets its own wording:
    label: str = ""              # the report's "What was evaluated" (default: the doc, else the name)
    badge: str = ""              # a short tag beside the report's title ('' none)
    rendered: bool = False       # images rendered by the project, not photographs: the report says the paper's
    #                              numbers are not expected, and the scorecard compares with §5.3/§5.4

    def check(self, cfg, need) -> None:
        """Cross-key checks: ``need(ok, message)`` raises a ConfigError naming the file."""

    def classes(self, cfg) -> tuple[str, ...] | None:
        """The classes ``models.classes = 'all'`` models, at most, when the config alone says."""
        return None

    def classes_words(self, cfg) -> str | None:
        """How the config error names where those classes come from (None: the default wording)."""
        return None

    def describe(self, data: dict, extra: dict) -> str:
        """The report's wording of the data, from the run's resolved ``[data]`` table and the data
        stage's manifest extras (a run read back later: not the live config)."""
        return self.label or self.doc or f"data source '{self.name}'"

    def category_targets(self, data: dict) -> bool:
        """Targets are categories whose every scored object is unseen (the paper tested none such;
        ``evaluate.statistics.cluster = 'category'`` needs them), from the resolved ``[data]`` table."""
        return False

    def input_key(self, cfg) -> str:
        """A fingerprint of inputs the data stage does not read through its own writes (e.g. roots
        read in place by later stages); '' when every input file it reads is recorded."""
        return ""

    def work(self, cfg) -> Work | None:
        """The views and crops this config makes the data and features stages handle; None (the
        default): not declared, so those stages are not estimated (logged) before they run."""
        return None

    def write(self, ctx) -> str:
        """The data stage: write ``bigbird/``, ``avd/``, ``truth.json`` and ``roots.json`` under
        ``ctx.out`` (``ctx.cfg``, ``ctx.skips``, ``ctx.extra`` for the manifest); returns the summary."""
        raise NotImplementedError(f"dataset source {self.name!r} has no write")

    # -- helpers for a source's own section --------------------------------------------------------
    def options(self, cfg) -> Any:
        """The source's own section (an instance of ``config``)."""
        return cfg.data.options

    def path(self, cfg, key: str) -> Path:
        """The path setting ``data.<name>.<key>`` resolved against the config's project root."""
        value = getattr(self.options(cfg), key)
        if not value:
            raise ConfigError(f"{cfg.source_path or 'config'}: 'data.{self.name}.{key}' must be set")
        return cfg.resolve(value)


def _adopt(name: str, obj, module: str) -> None:
    if isinstance(obj, DatasetSource) or (isinstance(obj, type) and issubclass(obj, DatasetSource)):
        register_dataset(obj, _module=module)
    else:
        raise TypeError(f"entry point {name!r} of {ENTRY_POINT_GROUP!r} names {obj!r}: not a module or a DatasetSource")


SOURCES: Registry[DatasetSource] = Registry("dataset source", ENTRY_POINT_GROUP, BUILTIN, static=STATIC,
                                            adopt=_adopt)


def problems(entry, *, complete: bool = False) -> list[str]:
    """Every breach of the dataset-source contract (empty: none): an identifier key (it names
    ``[data.<key>]``), text labels, a colour, a dataclass ``config``, and its data: a turntable
    source's ``read(cfg, skips)`` (``loaders.real_imagery.turntable``), any other's ``write(ctx)``,
    with the right signature; missing only with ``complete`` (``vf.check_extension``: a source
    registered for its report wording alone may leave them out, and the data stage names it)."""

    inst = entry.__new__(entry) if isinstance(entry, type) and issubclass(entry, DatasetSource) else entry
    if not isinstance(inst, DatasetSource):
        return [f"{entry!r:.60} is not a DatasetSource"]
    key, cls = X.declared_key(inst), type(inst)
    out = [None if isinstance(key, str) and key.isidentifier() else
           f"dataset source key {key!r:.60} must be an identifier (it names [data.<key>])",
           X.plain_name_problem(key) if key else None]
    for attr in ("label", "badge", "doc", "note"):
        out.append(X.text_problem(attr, getattr(inst, attr, "")))
    out.append(X.color_problem(getattr(inst, "color", None)))
    if inst.config is not None and not dataclasses.is_dataclass(inst.config):
        out.append("config must be a dataclass")
    # the hooks a source must write itself: DatasetSource's write(ctx), a TurntableSource's read
    decl = next(c for c in cls.__mro__ if "required_hooks" in vars(c))
    for hook, call, n in cls.required_hooks:
        if getattr(cls, hook, None) is getattr(decl, hook, None):
            out.append(f"{call} is not implemented" if complete else None)
        else:
            out.append(X.signature_problem(getattr(cls, hook), hook, call, inst, *([None] * n)))
    return [p for p in out if p]


def register_dataset(entry, *, _module: str | None = None):
    """Register a ``DatasetSource`` subclass (usable as a class decorator) or instance under its
    key; every breach of the contract (``problems``) is one ``ExtensionError`` naming it."""

    key = declared_key(entry) if isinstance(entry, (type, DatasetSource)) else ""
    raise_problems("dataset source", key or repr(entry)[:60], "register", problems(entry))
    inst = entry() if isinstance(entry, type) else entry
    inst.key = inst.name = key
    module = _module or type(inst).__module__
    old = SOURCES.peek(key)
    SOURCES.add(key, inst, module=module,
                replace=old is not None and type(old).__qualname__ == type(inst).__qualname__
                and SOURCES.module_of(key) == module)
    return entry


def unregister_dataset(name: str) -> None:
    SOURCES.remove(name)


def names() -> list[str]:
    """The registered sources: the built-ins, then the others in registration order."""
    return list(SOURCES)


def dataset_source(name: str, where: str = "config") -> DatasetSource:
    """The source ``data.source`` names, or a ConfigError listing the registered ones."""
    if name not in SOURCES:
        raise ConfigError(f"{where}: 'data.source' = {name!r} is not a registered dataset source (registered: "
                          f"{', '.join(SOURCES)}; add one with vf.register_dataset or a viewfuse.datasets entry point)")
    return SOURCES[name]


def described(name: str) -> DatasetSource:
    """The registered source of that name, or, for one not registered in this process (a run read
    back after its package was removed, or 'unknown'), a plain source that names it."""
    if name in SOURCES:
        return SOURCES[name]
    plain = DatasetSource()
    plain.name = name
    return plain


def source_config(data: dict, where: str) -> tuple[str, type | None]:
    """The source a ``[data]`` table names and the dataclass of its own ``[data.<name>]`` section
    (None for a source without one, or a ``source`` of the wrong type: the loader names it);
    the loader builds it like the methods' sections (``pipeline.infra.config.own``)."""
    name = data.get("source", "synthetic")
    if not isinstance(name, str):
        return "", None
    return name, dataset_source(name, where).config
