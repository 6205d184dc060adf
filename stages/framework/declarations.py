"""The config package's settings, left out of the code fingerprint (docs/design/stages.md, "What the
config package adds to a key").

A key of the config (``setting(...)`` in a section's dataclass: its default, range, choices, doc)
reaches a stage only through its resolved value, and the stage key already holds the resolved
sections the stage declares (``StageSpec.sections``, and its upstream's through their digests).
Hashing the declarations as code too made every stage of every run stale on any edit to any
config module, a reworded ``doc=`` included. So in the config package's modules those field
declarations leave the fingerprint (the field's name and type stay); everything that computes
stays in it: functions, methods, properties, module constants, the loader, the checks, a field
declared any other way (``dataclasses.field``: the root's internal fields).
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = ("pipeline", "infra", "config")   # the modules whose settings' declarations are left out
FIELDS = "pipeline.infra.config.fields"     # where ``setting`` is defined


def declares_settings(path: Path, root: Path) -> bool:
    """Whether ``path`` is a module of the config package under source tree ``root``."""
    return path.parent == root.joinpath(*PACKAGE)


def _setting_names(tree: ast.Module) -> set[str]:
    """The names ``setting`` is imported as (``from ...fields import setting as _f``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module == FIELDS or (node.level == 1 and node.module == "fields")):
            names.update(a.asname or a.name for a in node.names if a.name == "setting")
    return names


def without_declarations(tree: ast.Module) -> ast.Module:
    """``tree`` with every class-level ``name: type = setting(...)`` reduced to ``name: type``
    (in place; the tree is parsed for hashing only)."""
    names = _setting_names(tree)
    for node in ast.walk(tree):
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt in node.body:
            if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.value, ast.Call)
                    and isinstance(stmt.value.func, ast.Name) and stmt.value.func.id in names):
                stmt.value = None
    return tree
