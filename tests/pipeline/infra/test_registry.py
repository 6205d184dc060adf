"""The one registry mechanism (``pipeline.infra.registry``): built-ins first whatever was imported
first, a name registered twice refused, entry points loaded once and adopted, outside entries
alone in the fingerprint."""
from __future__ import annotations

import re
import sys
import types

import pytest

from pipeline.infra import registry as registry_module
from pipeline.infra.extension import ExtensionError
from pipeline.infra.registry import Registry, RegistryError

pytestmark = pytest.mark.plugins   # these registries load (monkeypatched) entry points

REG: Registry | None = None   # the registry the discovery test's modules register into


def _entry_points(monkeypatch, eps):
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None: [e for e in eps if e.group == group])


class EP:
    def __init__(self, group, name, value, obj):
        self.group, self.name, self.value, self._obj = group, name, value, obj
        self.loads = 0

    def load(self):
        self.loads += 1
        if isinstance(self._obj, BaseException):
            raise self._obj
        return self._obj


def test_an_entry_registered_before_the_builtins_load_lists_after_them(monkeypatch):
    _entry_points(monkeypatch, [])
    adopted = []
    reg = Registry("thing", "test.things", "fake_builtins", adopt=lambda n, o, m: adopted.append(n))
    reg.add("early", object(), module="__main__")           # a script's decorator, before any use
    mod = types.ModuleType("fake_builtins")
    monkeypatch.setitem(sys.modules, "fake_builtins", mod)
    reg.add("b1", object(), module="fake_builtins")          # the built-ins, imported later
    reg.add("b2", object(), module="fake_builtins.sub")
    assert list(reg) == ["b1", "b2", "early"]
    assert [reg.is_builtin(n) for n in reg] == [True, True, False] and len(reg) == 3
    with pytest.raises(RegistryError, match="thing 'b1' is registered twice"):
        reg.add("b1", object(), module="elsewhere")


def test_entry_points_load_once_in_name_order_and_unregistered_objects_are_adopted(monkeypatch):
    adopted = []
    reg = Registry("thing", "test.things", "fake_builtins",
                   adopt=lambda n, o, m: (adopted.append((n, m)), reg.add(n, o, module=m)))
    monkeypatch.setitem(sys.modules, "fake_builtins", types.ModuleType("fake_builtins"))
    z = EP("test.things", "zeta", "pkg.z:OBJ", "z-object")
    a = EP("test.things", "alpha", "pkg.a", types.ModuleType("pkg.a"))   # a module: its import registers
    other = EP("other.group", "x", "pkg.x:X", "x")
    _entry_points(monkeypatch, [z, a, other])
    assert list(reg) == ["zeta"] and reg["zeta"] == "z-object"
    assert adopted == [("zeta", "pkg.z")] and (z.loads, a.loads, other.loads) == (1, 1, 0)
    list(reg)
    assert z.loads == 1


@pytest.mark.parametrize("cause, words", [(ImportError("no module named nothere"), "ImportError: no module named nothere"),
                                          (SystemExit(0), "SystemExit: 0")])
def test_a_broken_entry_point_is_contained_and_named(monkeypatch, caplog, cause, words):
    """Any exception at an entry point's import, SystemExit included: the registry loads the rest,
    warns once naming the kind, the entry point and the cause, and ``check_loaded`` refuses with it."""
    monkeypatch.setitem(sys.modules, "fake_builtins", types.ModuleType("fake_builtins"))
    monkeypatch.setattr(registry_module, "FAILED", {})
    reg = Registry("thing", "test.things", "fake_builtins",
                   adopt=lambda n, o, m: reg.add(n, o, module=m))
    _entry_points(monkeypatch, [EP("test.things", "bad", "pkg.bad:X", cause), EP("test.things", "good", "pkg.g:Y", 1)])
    assert list(reg) == ["good"]
    why = "thing entry point 'bad' = 'pkg.bad:X' of group 'test.things' does not load: " + words
    assert reg.failures() == {"bad": why} and why in caplog.text
    with pytest.raises(ExtensionError, match=re.escape(why)):
        reg.check_loaded()
    reg.check_loaded({"good"})                         # a run that does not use it is not refused


def test_an_entry_point_that_registers_then_fails_leaves_nothing(monkeypatch):
    monkeypatch.setitem(sys.modules, "fake_builtins", types.ModuleType("fake_builtins"))
    monkeypatch.setattr(registry_module, "FAILED", {})
    reg = Registry("thing", "test.things", "fake_builtins")

    class Half:
        name, value = "half", "pkg.half"

        def load(self):
            reg.add("first", 1, module="pkg.half")
            reg.add("with_uncertainty", 2, module="pkg.half")
            reg.add("with_uncertainty", 3, module="pkg.half")       # a key registered twice
    monkeypatch.setattr(Half, "group", "test.things", raising=False)
    _entry_points(monkeypatch, [Half()])
    assert list(reg) == [] and "registered twice" in reg.failures()["half"]


def test_the_fingerprint_holds_the_entries_the_code_key_cannot_see(monkeypatch):
    _entry_points(monkeypatch, [])
    monkeypatch.setitem(sys.modules, "fake_builtins", types.ModuleType("fake_builtins"))
    reg = Registry("thing", "test.things", "fake_builtins", static=("fake_builtins",))
    reg.add("b1", object(), module="fake_builtins")
    assert reg.outside_fingerprint() == ""
    reg.add("mine", object(), module=__name__)               # this file's source stands for it
    fp = reg.outside_fingerprint()
    assert fp.startswith("mine=") and len(fp) == len("mine=") + 16
    reg.remove("mine")
    assert reg.outside_fingerprint() == ""


def test_a_failed_builtin_load_is_retried_not_taken_as_loaded(monkeypatch):
    _entry_points(monkeypatch, [])
    monkeypatch.delitem(sys.modules, "fake_missing_builtins", raising=False)
    reg = Registry("thing", "test.things", "fake_missing_builtins")
    for _ in range(2):
        with pytest.raises(ModuleNotFoundError, match="fake_missing_builtins"):
            len(reg)


def test_every_module_of_the_builtin_folder_is_discovered(monkeypatch, tmp_path):
    """A new built-in is its file alone: ``load`` imports each module of the folder, in name order."""
    _entry_points(monkeypatch, [])
    pkg = tmp_path / "fake_folder_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name in ("zz_last", "aa_first", "_private"):
        (pkg / f"{name}.py").write_text(f"from tests.pipeline.infra.test_registry import REG\n"
                                        f"REG.add({name!r}, 1, module=__name__)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for m in [m for m in sys.modules if m.startswith("fake_folder_pkg")]:
        monkeypatch.delitem(sys.modules, m)
    global REG
    REG = Registry("thing", "test.things", "fake_folder_pkg")
    assert list(REG) == ["aa_first", "zz_last"] and REG.is_builtin("zz_last")
