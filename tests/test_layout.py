"""The package layout is enforced, not only documented (docs/design.md, section 1): imports run
down the floors stages -> reports -> loaders -> pipeline, and inside ``pipeline/`` only along the
allowed arrows between its subpackages."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

FLOORS = {"pipeline": 0, "loaders": 1, "reports": 2, "stages": 3}
# pipeline subpackage -> the pipeline subpackages it may import (besides itself).
SUBPACKAGES = {
    "infra": set(),
    "method": {"infra"},
    "scoring": {"infra"},
    "evaluation": {"method", "scoring", "infra"},
}


def project_imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every absolute import of a project package, also inside functions."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.append((node.lineno, node.module))
            if node.module == "pipeline":  # "from pipeline import method"
                out += [(node.lineno, f"pipeline.{a.name}") for a in node.names]
    return [(ln, m) for ln, m in out if m.split(".")[0] in FLOORS]


def floor_violations(root: Path) -> list[str]:
    bad = []
    for floor, level in FLOORS.items():
        for path in sorted((root / floor).rglob("*.py")):
            for line, mod in project_imports(path):
                if FLOORS[mod.split(".")[0]] > level:
                    bad.append(f"{path.relative_to(root)}:{line} imports {mod}")
    return bad


def subpackage_violations(root: Path) -> list[str]:
    bad = []
    for path in sorted((root / "pipeline").rglob("*.py")):
        rel = path.relative_to(root / "pipeline")
        if len(rel.parts) < 2:
            if rel.name != "__init__.py":
                bad.append(f"pipeline/{rel}: module outside the subpackages {sorted(SUBPACKAGES)}")
            continue
        own = rel.parts[0]
        if own not in SUBPACKAGES:
            bad.append(f"pipeline/{rel}: unknown subpackage {own!r} (add it to docs/design.md and this test)")
            continue
        for line, mod in project_imports(path):
            parts = mod.split(".")
            if parts[0] != "pipeline" or len(parts) < 2 or parts[1] == own:
                continue
            if parts[1] not in SUBPACKAGES[own]:
                bad.append(f"pipeline/{rel}:{line} imports {mod} ({own} may import {sorted(SUBPACKAGES[own]) or 'nothing'})")
    return bad


def test_no_module_imports_a_floor_above_its_own():
    bad = floor_violations(ROOT)
    assert not bad, "imports up the floors:\n" + "\n".join(bad)


def test_pipeline_subpackages_import_only_along_allowed_arrows():
    bad = subpackage_violations(ROOT)
    assert not bad, "forbidden imports between pipeline subpackages:\n" + "\n".join(bad)


def test_every_subpackage_says_what_lives_there_and_what_it_may_import():
    import importlib

    for sub in SUBPACKAGES:
        doc = importlib.import_module(f"pipeline.{sub}").__doc__ or ""
        assert "May import" in doc, f"pipeline/{sub}/__init__.py docstring"


def _plant(tmp_path: Path, sub: str, source: str) -> Path:
    for s in SUBPACKAGES:
        (tmp_path / "pipeline" / s).mkdir(parents=True, exist_ok=True)
    for floor in FLOORS:
        (tmp_path / floor).mkdir(exist_ok=True)
    (tmp_path / "pipeline" / sub / "planted.py").write_text(source)
    return tmp_path


def test_the_checks_catch_a_planted_forbidden_import(tmp_path):
    root = _plant(tmp_path, "method", "def f():\n    from pipeline.evaluation.metrics import x\n")
    assert subpackage_violations(root) == [
        "pipeline/method/planted.py:2 imports pipeline.evaluation.metrics (method may import ['infra'])"]
    (root / "pipeline" / "infra" / "up.py").write_text("import stages.runner\n")
    assert floor_violations(root) == ["pipeline/infra/up.py:1 imports stages.runner"]
    (root / "pipeline" / "infra" / "up.py").write_text("from pipeline import method\n")
    assert any("infra/up.py:1 imports pipeline.method" in b for b in subpackage_violations(root))
    (root / "pipeline" / "infra" / "up.py").write_text("from pipeline.infra import cache\n")
    assert not [b for b in subpackage_violations(root) if "up.py" in b]
