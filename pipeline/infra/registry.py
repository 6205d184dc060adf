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

An entry point that does not load (any exception at its import or adoption, ``SystemExit``
included; a key registered twice is one) is contained: the registry loads the rest, logs one
warning per process naming the kind, the entry point and the cause, and keeps it in ``failures``;
the stages that would use the kind refuse with that message (``stages.framework.outside``), and
every other command (``--help``, ``status``, the stages that do not use it) runs. Only
``KeyboardInterrupt`` goes through. ``VIEWFUSE_BUILTINS_ONLY=1`` in the environment (the test
suite's default, tests/conftest.py) pins every registry to its built-ins and what the process
registers itself: no entry point is loaded, and entries loaded from one before are hidden.

``outside_fingerprint`` hashes the source of every entry's module that the stages' static code key
cannot see (not among ``static``), so the stages an outside entry affects rerun when it is added,
removed or edited.
"""
from __future__ import annotations

import importlib
import inspect
import logging
import os
import pkgutil
import sys
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

from pipeline.infra.extension import ExtensionError
from pipeline.infra.cache import sha256_bytes

T = TypeVar("T")
log = logging.getLogger("viewfuse")
# (group, entry point name) -> why it does not load: each is tried and warned about once per process
# (the registries that share a group, e.g. the methods' config sections and cost terms, see it once).
FAILED: dict[tuple[str, str], str] = {}
# What an entry point of each group is, in messages (whichever registry of the group loads it first).
GROUP_KINDS = {"viewfuse.methods": "fusion method", "viewfuse.classifiers": "classifier",
               "viewfuse.planners": "planner", "viewfuse.metrics": "metric", "viewfuse.datasets": "dataset source"}
PIN = "VIEWFUSE_BUILTINS_ONLY"


def pinned() -> bool:
    """Whether the registries hold their built-ins only (``VIEWFUSE_BUILTINS_ONLY`` = 1)."""
    return os.environ.get(PIN, "") not in ("", "0")


class RegistryError(ExtensionError):
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
        self._from_eps: set[str] = set()     # names an entry point's import registered
        self._loaded = False
        self._eps_loaded = False

    # -- registering ------------------------------------------------------------------------------
    def add(self, name: str, entry: T, *, module: str, replace: bool = False) -> T:
        """Register ``entry`` under ``name``, defined in ``module`` (which decides built-in or not).
        The same name twice is an error unless ``replace`` (the same definition re-imported)."""
        if name in self._entries and not replace:
            raise RegistryError(f"{self.kind} {name!r} is registered twice ({self._modules[name]}, {module})",
                                kind=self.kind, key=name, hook="register", cause="registered twice")
        self._entries[name] = entry
        self._modules[name] = module
        return entry

    def remove(self, name: str) -> None:
        self._entries.pop(name, None)
        self._modules.pop(name, None)
        self._from_eps.discard(name)

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
        """Built-ins and the built-in folder (once per process), then the entry points (once, when
        the registry is not pinned to its built-ins)."""
        if not self._loaded:
            self._loaded = True  # before importing: modules that register look the registry up
            try:
                self._load_builtins()
            except BaseException:
                self._loaded = False  # a failed load is not a loaded registry: the next use retries and fails alike
                raise
        if not self._eps_loaded and not pinned():
            self._eps_loaded = True
            self._load_entry_points()

    def _load_builtins(self) -> None:
        pkg = importlib.import_module(self.builtin)
        for info in sorted(pkgutil.iter_modules(getattr(pkg, "__path__", [])), key=lambda i: i.name):
            if not info.name.startswith("_"):
                importlib.import_module(f"{self.builtin}.{info.name}")

    def _load_entry_points(self) -> None:
        from importlib.metadata import entry_points

        for ep in sorted(entry_points(group=self.group), key=lambda e: e.name):
            if (self.group, ep.name) in FAILED:
                continue
            before = set(self._entries)
            try:
                obj = ep.load()
                if set(self._entries) == before and not inspect.ismodule(obj) and self._adopt is not None:
                    self._adopt(ep.name, obj, ep.value.partition(":")[0].strip())
            except KeyboardInterrupt:
                raise
            except BaseException as e:  # noqa: BLE001 - SystemExit too: contained, named, kept
                for name in set(self._entries) - before:   # what it registered before failing goes too
                    self.remove(name)
                why = (f"{GROUP_KINDS.get(self.group, self.kind)} entry point {ep.name!r} = {ep.value!r} of group "
                       f"{self.group!r} does not load: {type(e).__name__}: {e}")
                FAILED[(self.group, ep.name)] = why
                log.warning("%s (skipped; the stages that use it refuse to run)", why)
                continue
            self._from_eps |= set(self._entries) - before

    def failures(self) -> dict[str, str]:
        """{entry point name: why it does not load} of this registry's group (empty when pinned)."""
        self.load()
        return {} if pinned() else {n: why for (g, n), why in FAILED.items() if g == self.group}

    def check_loaded(self, names=None) -> None:
        """``ExtensionError`` naming the entry points of this group that do not load (those named in
        ``names``, when given: the entries a run uses)."""
        bad = [why for n, why in self.failures().items() if names is None or n in names]
        if bad:
            raise RegistryError("; ".join(bad), kind=self.kind, key=", ".join(self.failures()), hook="import",
                                cause=bad[0])

    # -- the mapping (loads on first use) ---------------------------------------------------------
    def _visible(self) -> list[str]:
        self.load()
        hidden = self._from_eps if pinned() else set()
        return [n for n in self._entries if n not in hidden]

    def _order(self) -> list[str]:
        names = self._visible()
        return [n for n in names if self.is_builtin(n)] + [n for n in names if not self.is_builtin(n)]

    def __getitem__(self, name: str) -> T:
        self.load()
        if pinned() and name in self._from_eps:
            raise KeyError(name)
        return self._entries[name]

    def __contains__(self, name: object) -> bool:
        self.load()
        return name in self._entries and not (pinned() and name in self._from_eps)

    def __iter__(self) -> Iterator[str]:
        return iter(self._order())

    def __len__(self) -> int:
        return len(self._visible())

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
