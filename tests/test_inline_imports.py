"""In-function imports of the project's own modules only where the import is heavy or optional.

An import inside a function hides an arrow of the import graph from a reader (the circle test in
tests/test_layout.py counts them all the same). One stays inside a function only where importing
at the top would cost every importer of the module: the target pulls, at its own top level,
directly or through other project modules, a heavy library (``HEAVY``); or the target is
optional (its import is guarded by ``except ImportError``). Both are computed here from the
code, not listed. ``ALLOWED`` holds the remaining in-function imports that are neither, each
with its reason; the list only shrinks: a new in-function import that is neither fails."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("pipeline", "loaders", "reports", "stages", "viewfuse")
# Libraries whose import costs a command (seconds, hundreds of MB) that may never need them.
HEAVY = {"torch", "torchvision", "sklearn", "scipy", "matplotlib", "ray", "cv2", "pandas", "pyarrow", "h5py",
         "PIL", "plotly", "numba", "onnxruntime", "efficientnet_lite_pytorch", "pydantic"}


def _functions_imports(tree) -> tuple[list[tuple[int, str, bool]], list[str]]:
    """(in-function imports as (line, module, guarded by except ImportError), top-level modules)."""
    inner, top = [], []

    def visit(node, in_fn: bool, guarded: bool):
        for ch in ast.iter_child_nodes(node):
            fn = in_fn or isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            g = guarded or (isinstance(ch, ast.Try) and any(
                h.type is not None and "ImportError" in ast.unparse(h.type) for h in ch.handlers))
            if isinstance(ch, (ast.Import, ast.ImportFrom)):
                mods = [a.name for a in ch.names] if isinstance(ch, ast.Import) else \
                    ([ch.module] + [f"{ch.module}.{a.name}" for a in ch.names] if ch.module and not ch.level else [])
                if fn:
                    inner.append((ch.lineno, mods, g))
                else:
                    top.extend(mods)
            visit(ch, fn, g)

    visit(tree, False, False)
    return inner, top


def _modules(root: Path) -> dict[str, Path]:
    out = {}
    for floor in PROJECT:
        for p in sorted((root / floor).rglob("*.py")):
            parts = list(p.relative_to(root).with_suffix("").parts)
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def heavy_at_import(root: Path) -> dict[str, str]:
    """{project module: the heavy library importing it pulls in (its top level, transitively)}."""
    mods = _modules(root)
    top = {m: _functions_imports(ast.parse(p.read_text()))[1] for m, p in mods.items()}
    memo: dict[str, str] = {}

    def heavy(m: str, seen: frozenset) -> str:
        if m in memo:
            return memo[m]
        found = ""
        parents = [".".join(m.split(".")[:i]) for i in range(1, m.count(".") + 1)]
        for t in [*parents, *top.get(m, [])]:
            if t.split(".")[0] in HEAVY:
                found = t.split(".")[0]
            elif t in mods and t not in seen:
                found = heavy(t, seen | {t})
            if found:
                break
        memo[m] = found
        return found

    return {m: heavy(m, frozenset({m})) for m in mods}


def inline_imports(root: Path) -> list[tuple[str, str, str]]:
    """(file:line, module, why it may stay: '' when neither heavy nor optional) of every
    in-function import of a project module."""
    mods, heavy = _modules(root), heavy_at_import(root)
    out = []
    for m, p in mods.items():
        inner, _ = _functions_imports(ast.parse(p.read_text()))
        for line, names, guarded in inner:
            found = [t for t in names if t in mods]
            # ``from a.b import c`` of a module c imports a.b.c (a.b runs on the way)
            targets = [t for t in found if not any(o.startswith(t + ".") for o in found)]
            for target in targets:
                heavy_lib = next((heavy[t] for t in targets if heavy.get(t)), "")
                why = "optional" if guarded else (f"heavy ({heavy_lib})" if heavy_lib else "")
                out.append((f"{p.relative_to(root).as_posix()}:{line}", target, why))
    return out


# file -> {module imported inside a function: why it is not at the top}. Neither heavy nor optional.
ALLOWED: dict[str, dict[str, str]] = {
}


def unjustified(root: Path, allowed=None) -> list[str]:
    allowed = ALLOWED if allowed is None else allowed
    bad = []
    for where, target, why in inline_imports(root):
        if not why and target not in allowed.get(where.rsplit(":", 1)[0], {}):
            bad.append(f"{where} imports {target} inside a function (neither heavy nor optional: import it at the top)")
    return bad


def test_in_function_imports_of_project_modules_are_heavy_optional_or_listed():
    bad = unjustified(ROOT)
    assert not bad, "\n".join(bad)


def test_the_walk_tells_heavy_optional_and_plain_in_function_imports_apart(tmp_path):
    for d in PROJECT:
        (tmp_path / d).mkdir()
    (tmp_path / "pipeline" / "__init__.py").write_text("")
    (tmp_path / "pipeline" / "net.py").write_text("import torch\n")
    (tmp_path / "pipeline" / "uses_net.py").write_text("from pipeline import net\n")
    (tmp_path / "pipeline" / "light.py").write_text("X = 1\n")
    (tmp_path / "pipeline" / "user.py").write_text(
        "def a():\n    from pipeline.uses_net import net\n"
        "def b():\n    try:\n        import pipeline.light\n    except ImportError:\n        pass\n"
        "def c():\n    from pipeline.light import X\n")
    found = set(inline_imports(tmp_path))
    assert found == {("pipeline/user.py:2", "pipeline.uses_net", "heavy (torch)"),
                     ("pipeline/user.py:5", "pipeline.light", "optional"),
                     ("pipeline/user.py:9", "pipeline.light", "")}
    assert unjustified(tmp_path, {}) == [
        "pipeline/user.py:9 imports pipeline.light inside a function (neither heavy nor optional: import it at the top)"]
    assert unjustified(tmp_path, {"pipeline/user.py": {"pipeline.light": "a reason"}}) == []
