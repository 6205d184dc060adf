"""Config sections that extensions declare: a method's model provider (``[models.<key>]``,
``[evaluate.<key>]``: ``pipeline.method.provider``) or a dataset source (``[data.<name>]``:
``pipeline.infra.datasets``). One mechanism for both: the section's dataclass of ``setting``
fields is read and range-checked by the loader like every built-in section, with errors naming
the dotted key; the built instances sit in the parent section's ``own`` (an ``Own``), read as
attributes (``cfg.models.<key>``); ``to_dict`` writes them where the TOML has them, so the
section hashes that stage keys use, and a run's recorded config, include them.

The registered sections (``SECTIONS``) load like the methods (``pipeline.infra.registry``): the
built-in methods' package, then the ``viewfuse.methods`` entry points, on first use in every
process, so a config is never parsed before the methods declared theirs. A dataset source's
section is the one of the source ``data.source`` names, present only then.

An extension may also add one key to the parent section itself (``[models] <name> = true``), where
a table would be too much: declared as a ``Key`` (its type and its ``setting`` field), read as
``cfg.models.<name>`` and written by ``to_dict`` as a key of the parent, like a built-in one.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from pipeline.infra.datasets import source_config
from pipeline.infra.registry import Registry

# The sections extensions may add tables to (each a dataclass deriving from Extendable).
PARENTS = ("data", "models", "evaluate")


@dataclass(frozen=True)
class Key:
    """One key an extension adds to its parent section (``[<parent>] <name> = <value>``): its
    ``type`` (bool, int, float or str) and its ``setting`` field (default, range, choices, doc)."""
    type: type
    field: dataclasses.Field

    def default(self) -> Any:
        f = self.field
        return f.default_factory() if f.default is dataclasses.MISSING else f.default


def default_of(declared: Any) -> Any:
    """A declared section's or key's default value (an own section or key not in the TOML)."""
    return declared.default() if isinstance(declared, Key) else declared()


@dataclass(frozen=True)
class Declared:
    """What one extension (a model provider, by its key) declares: ``sections``, dotted TOML table
    -> its frozen dataclass of ``setting`` fields (``{"models.<key>": ..., "evaluate.<key>": ...}``),
    or dotted key -> a ``Key`` (one key of the parent section);
    ``check(cfg, need)``, its cross-key checks (``need(ok, message)`` raises a ConfigError naming
    the file), run with every section's at load."""
    owner: str
    sections: dict[str, type]
    check: Callable | None = None


SECTIONS: Registry[Declared] = Registry("config section", "viewfuse.methods", "pipeline.method.methods")


def register_sections(owner: str, sections: dict[str, type], *, check: Callable | None = None, module: str) -> None:
    """Declare ``owner``'s sections (each ``<parent>.<name>``), defined in ``module``; the same
    module registering again (a re-import) replaces its entry, another module's is an error."""
    for path, config in sections.items():
        parent, _, name = path.partition(".")
        if parent not in PARENTS or not name.isidentifier():
            raise ValueError(f"{owner}: config section {path!r} must be <parent>.<name> with parent one of "
                             f"{', '.join(PARENTS)}")
        if isinstance(config, Key):
            if config.type not in (bool, int, float, str) or not isinstance(config.field, dataclasses.Field):
                raise TypeError(f"{owner}: config key {path!r} must be a Key of bool, int, float or str with a "
                                f"setting field, got {config!r:.80}")
        elif not (dataclasses.is_dataclass(config) and isinstance(config, type)):
            raise TypeError(f"{owner}: config section {path!r} must be a dataclass or a Key, got {config!r:.80}")
    old = SECTIONS.peek(owner)
    SECTIONS.add(owner, Declared(owner, dict(sections), check), module=module,
                 replace=old is not None and SECTIONS.module_of(owner) == module)


def unregister_sections(owner: str) -> None:
    SECTIONS.remove(owner)


def registered(parent: str) -> dict[str, Any]:
    """The registered sections under ``[parent]``: name -> dataclass or ``Key`` (two owners of one
    is an error)."""
    out: dict[str, type] = {}
    owners: dict[str, str] = {}
    for d in SECTIONS.values():
        for path, config in d.sections.items():
            p, _, name = path.partition(".")
            if p == parent:
                if name in out:
                    raise ValueError(f"config section {path!r} is declared by both {owners[name]!r} and {d.owner!r}")
                out[name], owners[name] = config, d.owner
    return out


def sections(parent: str, table: dict, where: str) -> dict[str, type]:
    """The own sections of ``[parent]`` while loading its ``table``: name -> dataclass (the
    registered ones and, under ``data``, the section of the source it names)."""
    out = registered(parent)
    if parent == "data":
        name, config = source_config(table, where)
        if config is not None:
            out[name] = config
    return out


def checks() -> list[Callable]:
    return [d.check for d in SECTIONS.values() if d.check is not None]


class Own(Mapping):
    """The own sections of one parent section: name -> instance. Those not built (a section made
    in code, ``ModelsConfig()``) read as the registered section's defaults, so a hand-made config
    equals a loaded one and hashes alike. Immutable and hashable, like the sections."""

    def __init__(self, parent: str, items: Mapping[str, Any] | None = None):
        self._parent, self._items = parent, dict(items or {})

    def _all(self) -> dict[str, Any]:
        return {**{n: default_of(c) for n, c in registered(self._parent).items() if n not in self._items},
                **self._items}

    def __getitem__(self, name: str) -> Any:
        if name in self._items:
            return self._items[name]
        return self._all()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._all()))

    def __len__(self) -> int:
        return len(self._all())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Own) and self._parent == other._parent and self._all() == other._all()

    def __hash__(self) -> int:
        return hash((self._parent, tuple(sorted(self._all().items()))))

    def __repr__(self) -> str:
        return f"Own({self._parent!r}, {self._all()!r})"

    def built(self, name: str) -> Any:
        """The section ``name`` as loaded, or None (no default: a dataset source's section)."""
        return self._items.get(name)

    def replace(self, **values: Any) -> Own:
        """A copy with the named sections replaced (for code that builds configs)."""
        return Own(self._parent, {**self._items, **values})


def own_field(parent: str) -> Any:
    """The ``own`` field of an extendable section: not a TOML key, written by ``to_dict`` in place."""
    return dataclasses.field(default_factory=lambda: Own(parent), metadata={"internal": True, "own": True})


class Extendable:
    """A section extensions add tables to: ``cfg.models.<key>`` reads ``own[<key>]``."""

    def __getattr__(self, name: str) -> Any:
        own = self.__dict__.get("own") if not name.startswith("__") else None
        if own is not None and name in own:
            return own[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


def own_items(obj: Any) -> list[tuple[str, Any]]:
    """The own sections of a section (empty for any other object), by name."""
    own = obj.__dict__.get("own") if isinstance(obj, Extendable) else None
    return [(k, own[k]) for k in own] if own is not None else []


def with_own(section: Any, **values: Any) -> Any:
    """``section`` with the named own sections replaced (``with_own(cfg.models, <key>=...)``)."""
    return dataclasses.replace(section, own=section.own.replace(**values))
