"""Everything the product code imports at module level is a runtime dependency: a module-level
import of a package that only an extra declares (psutil was once in [test] only) makes
``pip install viewfuse`` unable to import the stages. A code walk over the product packages'
module-level imports (inside a module-level ``try``/``if`` too) against [project.dependencies];
the standard library and the project's own packages are excluded, and a function-level import
(an optional feature such as ray) is the function's business."""
from __future__ import annotations

import ast
import importlib.metadata as md
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("pipeline", "loaders", "reports", "stages", "viewfuse")


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def declared(pyproject: Path) -> set[str]:
    """The distribution names of [project.dependencies] (markers and versions dropped)."""
    deps = tomllib.loads(pyproject.read_text())["project"]["dependencies"]
    return {_norm(re.match(r"\s*([A-Za-z0-9_.\-]+)", d).group(1)) for d in deps}


def module_level_imports(path: Path) -> set[str]:
    """Top-level names of the absolute imports a module runs when it is imported."""
    out: set[str] = set()
    for node in ast.parse(path.read_text(), str(path)).body:
        for n in ast.walk(node) if isinstance(node, (ast.Try, ast.If)) else (node,):
            if isinstance(n, ast.Import):
                out.update(a.name.split(".")[0] for a in n.names)
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                out.add(n.module.split(".")[0])
    return out


def undeclared(root: Path, packages, deps: set[str]) -> dict[str, list[str]]:
    """{imported module: [files]} for each module-level import that no declared distribution
    provides (a module no installed distribution provides counts as undeclared)."""
    providers = md.packages_distributions()
    own = set(packages)
    found: dict[str, list[str]] = {}
    for pkg in packages:
        for f in sorted((root / pkg).rglob("*.py")):
            for mod in module_level_imports(f):
                if mod in sys.stdlib_module_names or mod in own or mod == "__future__":
                    continue
                # a declared module this interpreter lacks (tomli below 3.11 only) goes by its name
                if not ({_norm(d) for d in providers.get(mod, ())} | {_norm(mod)}) & deps:
                    found.setdefault(mod, []).append(str(f.relative_to(root)))
    return found


def test_every_module_level_import_of_the_product_is_a_runtime_dependency():
    bad = undeclared(ROOT, PRODUCT, declared(ROOT / "pyproject.toml"))
    assert not bad, ("imported at module level but not in [project.dependencies] (an extra is not "
                     f"installed by `pip install viewfuse`): {bad}")


def test_the_walk_finds_a_planted_import_an_extra_declares(tmp_path):
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "ok.py").write_text("import os\nimport numpy as np\nfrom pkg import sub\n"
                                            "def f():\n    import psutil  # function level: not counted\n")
    (tmp_path / "pkg" / "sub" / "m.py").write_text("try:\n    import psutil\nexcept ImportError:\n    pass\n")
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\ndependencies = ["numpy>=1", "tomli; '
                                             'python_version < \'3.11\'"]\n[project.optional-dependencies]\n'
                                             'test = ["psutil"]\n')
    deps = declared(tmp_path / "pyproject.toml")
    assert deps == {"numpy", "tomli"}
    assert undeclared(tmp_path, ("pkg",), deps) == {"psutil": ["pkg/sub/m.py"]}
    # a module no installed distribution provides is reported too
    (tmp_path / "pkg" / "ok.py").write_text("import not_a_real_module_xyz\n")
    assert "not_a_real_module_xyz" in undeclared(tmp_path, ("pkg",), deps)


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("VIEWFUSE_TEST_INSTALL") != "1",
                    reason="installs the package and torch into a fresh venv (several minutes, several GB): "
                           "`make test-install` runs it (VIEWFUSE_TEST_INSTALL=1)")
def test_a_fresh_venv_without_extras_runs_the_smoke_chain(tmp_path):
    """``pip install .`` (no extras, no site packages) into a fresh venv, then the smoke chain
    through that venv's own ``viewfuse`` command, outside the source tree."""
    venv = tmp_path / "venv"
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(ROOT)], check=True)
    installed = time.monotonic() - t0
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    r = subprocess.run([str(venv / "bin" / "viewfuse"), "report", "--config", str(ROOT / "configs" / "smoke.toml")],
                       cwd=work, env=env, capture_output=True, text=True)
    assert r.returncode == 0, f"smoke chain in the fresh venv failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    print(f"fresh install {installed:.0f} s, smoke chain {time.monotonic() - t0 - installed:.0f} s")
