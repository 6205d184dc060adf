"""One registry mechanism for every kind of extension (fusion methods, classifiers, planners,
metrics): a ``Registry`` is an ordered, read-only mapping name -> entry, filled by a decorator or a
call, by the kind's built-in folder or module, and by the kind's entry-point group
(``viewfuse.<kind>``) of any installed package.

Order is the order of tables, figures and rows, so it never depends on what was imported first:
the built-ins (entries defined in the kind's built-in package or module) come first, in their
registration order, then every other entry in its registration order. An entry registered before
the built-ins were loaded (``@vf.register`` at the top of a script) still lists after them.

Loading is lazy and happens in every process on first use of the mapping (a Ray worker that looks
a name up loads the same built-ins and entry points as the driver): import the built-in package
(and every module of its folder, so a new built-in is its file alone), then load each entry point
of the group in name order. An entry point names a module (importing it registers) or an object
(registered under the entry point's name, as defined in the entry point's module, when the import
did not register it already).

``outside_fingerprint`` hashes the source of every entry's module that the stages' static code key
cannot see (not among ``static``), so the stages an outside entry affects rerun when it is added,
removed or edited.
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil
import sys
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

from pipeline.infra.cache import sha256_bytes

T = TypeVar("T")


class RegistryError(ValueError):
    """An entry registered twice, or an entry point that does not load."""


def caller_module(depth: int = 2) -> str:
    """The ``__name__`` of the module that called the function calling this one (``depth`` frames up)."""
    return str(sys._getframe(depth).f_globals.get("__name__", "__main__"))


class Registry(Mapping, Generic[T]):
    """Entries of one kind. ``builtin``: the package or module holding the built-ins (a package's
    modules are all imported); ``static``: the built-in modules the stages' code key already
    covers (imported by name somewhere a stage reaches); ``adopt``: turns what an entry point
    names (a class, an instance) into a registration when importing it registered nothing."""

    def __init__(self, kind: str, group: str, builtin: str, *, static: tuple[str, ...] = (),
                 adopt: Callable[[str, Any, str], None] | None = None):
        self.kind, self.group, self.builtin = kind, group, builtin
        self.static = frozenset(static)
        self._adopt = adopt
        self._entries: dict[str, T] = {}
        self._modules: dict[str, str] = {}
        self._loaded = False

    # -- registering ------------------------------------------------------------------------------
    def add(self, name: str, entry: T, *, module: str, replace: bool = False) -> T:
        """Register ``entry`` under ``name``, defined in ``module`` (which decides built-in or not).
        The same name twice is an error unless ``replace`` (the same definition re-imported)."""
        if name in self._entries and not replace:
            raise RegistryError(f"{self.kind} {name!r} is registered twice ({self._modules[name]}, {module})")
        self._entries[name] = entry
        self._modules[name] = module
        return entry

    def remove(self, name: str) -> None:
        self._entries.pop(name, None)
        self._modules.pop(name, None)

    def pop(self, name: str, default=None):
        """Remove ``name`` and return its entry (``default`` when there is none)."""
        entry = self._entries.get(name, default)
        self.remove(name)
        return entry

    def peek(self, name: str) -> T | None:
        """The entry under ``name`` without loading anything (for registering code)."""
        return self._entries.get(name)

    def is_builtin(self, name: str) -> bool:
        m = self._modules[name]
        return m == self.builtin or m.startswith(self.builtin + ".")

    def module_of(self, name: str) -> str:
        return self._modules[name]

    # -- loading ----------------------------------------------------------------------------------
    def load(self) -> None:
        """Built-ins, the built-in folder, then the entry points (once per process)."""
        if self._loaded:
            return
        self._loaded = True  # before importing: modules that register look the registry up
        try:
            self._load_all()
        except BaseException:
            self._loaded = False  # a failed load is not a loaded registry: the next use retries and fails alike
            raise

    def _load_all(self) -> None:
        pkg = importlib.import_module(self.builtin)
        for info in sorted(pkgutil.iter_modules(getattr(pkg, "__path__", [])), key=lambda i: i.name):
            if not info.name.startswith("_"):
                importlib.import_module(f"{self.builtin}.{info.name}")
        from importlib.metadata import entry_points

        for ep in sorted(entry_points(group=self.group), key=lambda e: e.name):
            before = set(self._entries)
            try:
                obj = ep.load()
            except Exception as e:  # noqa: BLE001 - re-raised naming the entry point
                raise RegistryError(f"entry point {ep.name!r} = {ep.value!r} of group {self.group!r} "
                                    f"does not load: {type(e).__name__}: {e}") from e
            if set(self._entries) == before and not inspect.ismodule(obj) and self._adopt is not None:
                self._adopt(ep.name, obj, ep.value.partition(":")[0].strip())

    # -- the mapping (loads on first use) ---------------------------------------------------------
    def _order(self) -> list[str]:
        self.load()
        names = list(self._entries)
        return [n for n in names if self.is_builtin(n)] + [n for n in names if not self.is_builtin(n)]

    def __getitem__(self, name: str) -> T:
        self.load()
        return self._entries[name]

    def __contains__(self, name: object) -> bool:
        self.load()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._order())

    def __len__(self) -> int:
        self.load()
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {self._order()})"

    # -- the cache key ----------------------------------------------------------------------------
    def outside(self) -> list[str]:
        """Entries whose module the stages' static code key does not cover, in order."""
        return [n for n in self._order() if self._modules[n] not in self.static]

    def outside_fingerprint(self, names=None) -> str:
        """``name=sha256(module source)[:16]`` of every ``outside`` entry (of those in ``names``,
        when given: the ones a run uses), joined by ``;``."""
        return ";".join(f"{n}={source_digest(self._modules[n], self._entries[n])}" for n in self.outside()
                        if names is None or n in names)


def source_digest(module: str, entry: Any) -> str:
    """sha256 of the defining module's source; an entry defined interactively (no source file)
    stands in by its class's attributes."""
    try:
        src = inspect.getsource(sys.modules[module])
    except (KeyError, OSError, TypeError):
        cls = entry if isinstance(entry, type) else type(entry)
        src = repr(sorted((k, repr(v)) for k, v in vars(cls).items()))
    return sha256_bytes(src.encode())[:16]
