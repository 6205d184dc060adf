"""The package layout is enforced, not only documented (docs/design.md, section 1): imports run
down the floors stages -> reports -> loaders -> pipeline; inside ``pipeline/`` only along the
allowed arrows between its subpackages and between the evaluation's sub-rooms; report pages import
the shared room, never each other; a stage imports the stage framework, never another stage or a
command; and no module imports another module's private (``_``-prefixed) name."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FLOORS = {"pipeline": 0, "loaders": 1, "reports": 2, "stages": 3}
# pipeline subpackage -> the pipeline subpackages it may import (besides itself).
SUBPACKAGES = {
    "infra": set(),
    "scene": {"infra"},
    "method": {"infra"},
    "scoring": {"infra"},
    "evaluation": {"method", "scoring", "scene", "infra"},
    "banks": {"evaluation", "method", "scoring", "infra"},
    "planning": {"evaluation", "method", "infra"},
}
# What the dataset floor may use of pipeline/: the plumbing and the geometry, never the protocol.
LOADER_SUBPACKAGES = {"infra", "scene", "method"}
# pipeline/evaluation sub-room -> the sub-rooms it may import (besides itself).
EVALUATION_ROOMS = {
    "metrics": set(),
    "statistics": {"metrics"},
    "grid": {"metrics", "statistics"},
    "simulation": {"metrics", "statistics"},
    "domain": {"grid", "metrics", "statistics"},
    "calibration": {"metrics", "statistics"},
}
REPORT_ROOMS = {"shared": set(), "main": {"shared"}, "simulate": {"shared"}, "compare": {"shared"},
                "study": {"shared"}}
STAGE_ROOMS = ("framework", "commands")  # stages/<room>/; every other stages/<name>.py is a stage


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


def _imports_by_module(root: Path, floor: str):
    for path in sorted((root / floor).rglob("*.py")):
        yield path, project_imports(path)


def room_violations(root: Path) -> list[str]:
    """Arrows between the sub-rooms of pipeline/evaluation, of reports/ and of stages/."""
    bad = []
    for path, imports in _imports_by_module(root, "pipeline"):
        rel = path.relative_to(root / "pipeline").parts
        if len(rel) < 3 or rel[0] != "evaluation":
            continue
        own = rel[1]
        if own not in EVALUATION_ROOMS:
            bad.append(f"pipeline/{'/'.join(rel)}: unknown evaluation room {own!r}")
            continue
        for line, mod in imports:
            parts = mod.split(".")
            if parts[:2] == ["pipeline", "evaluation"] and len(parts) > 2 and parts[2] != own \
                    and parts[2] not in EVALUATION_ROOMS[own]:
                bad.append(f"pipeline/{'/'.join(rel)}:{line} imports {mod} "
                           f"(evaluation.{own} may import {sorted(EVALUATION_ROOMS[own]) or 'no other room'})")
    for path, imports in _imports_by_module(root, "reports"):
        rel = path.relative_to(root / "reports").parts
        if len(rel) < 2:
            if rel[0] != "__init__.py":
                bad.append(f"reports/{rel[0]}: module outside the page rooms {sorted(REPORT_ROOMS)}")
            continue
        own = rel[0]
        if own not in REPORT_ROOMS:
            bad.append(f"reports/{'/'.join(rel)}: unknown report room {own!r}")
            continue
        for line, mod in imports:
            parts = mod.split(".")
            if parts[0] == "reports" and (len(parts) < 2 or (parts[1] != own and parts[1] not in REPORT_ROOMS[own])):
                bad.append(f"reports/{'/'.join(rel)}:{line} imports {mod} (a report page imports reports.shared only)")
    for path, imports in _imports_by_module(root, "stages"):
        rel = path.relative_to(root / "stages").parts
        own = rel[0] if len(rel) > 1 else None
        if own is None and rel[0] == "__init__.py":
            continue
        for line, mod in imports:
            parts = mod.split(".")
            if parts[0] != "stages":
                continue
            target = parts[1] if len(parts) > 1 else ""
            if own is None:  # a stage module
                if target != "framework":
                    bad.append(f"stages/{rel[0]}:{line} imports {mod} (a stage imports stages.framework only)")
            elif own == "framework" and target != "framework":
                bad.append(f"stages/{'/'.join(rel)}:{line} imports {mod} (the framework names stages by string)")
    return bad


def private_name_violations(root: Path) -> list[str]:
    """``from a.b import _c`` (or ``a.b._c``) of another project module's private name."""
    bad = []
    for floor in FLOORS:
        for path in sorted((root / floor).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.module and not node.level \
                        and node.module.split(".")[0] in FLOORS:
                    for a in node.names:
                        if a.name.startswith("_") and not a.name.startswith("__"):
                            bad.append(f"{path.relative_to(root)}:{node.lineno} imports {node.module}.{a.name}")
    return bad


def test_rooms_import_only_along_their_arrows():
    bad = room_violations(ROOT)
    assert not bad, "forbidden imports between rooms:\n" + "\n".join(bad)


def test_no_module_imports_another_modules_private_name():
    bad = private_name_violations(ROOT)
    assert not bad, "imports of private names:\n" + "\n".join(bad)


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
    rooms = [f"pipeline.evaluation.{r}" for r in EVALUATION_ROOMS] + [f"reports.{r}" for r in REPORT_ROOMS] \
        + [f"stages.{r}" for r in STAGE_ROOMS]
    for room in rooms:
        assert (importlib.import_module(room).__doc__ or "").strip(), f"{room}: __init__.py says what lives there"


def _plant(tmp_path: Path, sub: str, source: str) -> Path:
    for s in SUBPACKAGES:
        (tmp_path / "pipeline" / s).mkdir(parents=True, exist_ok=True)
    for floor in FLOORS:
        (tmp_path / floor).mkdir(exist_ok=True)
    (tmp_path / "pipeline" / sub / "planted.py").write_text(source)
    return tmp_path


def test_the_checks_catch_a_planted_forbidden_import(tmp_path):
    root = _plant(tmp_path, "method", "def f():\n    from pipeline.evaluation.metrics.spec import x\n")
    assert subpackage_violations(root) == [
        "pipeline/method/planted.py:2 imports pipeline.evaluation.metrics.spec (method may import ['infra'])"]
    (root / "pipeline" / "infra" / "up.py").write_text("import stages.framework.runner\n")
    assert floor_violations(root) == ["pipeline/infra/up.py:1 imports stages.framework.runner"]
    (root / "pipeline" / "infra" / "up.py").write_text("from pipeline import method\n")
    assert any("infra/up.py:1 imports pipeline.method" in b for b in subpackage_violations(root))
    (root / "pipeline" / "infra" / "up.py").write_text("from pipeline.infra import cache\n")
    assert not [b for b in subpackage_violations(root) if "up.py" in b]


def test_the_room_checks_catch_planted_violations(tmp_path):
    root = _plant(tmp_path, "evaluation", "")
    for d in ("pipeline/evaluation/metrics", "reports/main", "reports/shared", "stages/framework"):
        (root / d).mkdir(parents=True, exist_ok=True)
    (root / "pipeline/evaluation/metrics/up.py").write_text("from pipeline.evaluation.grid.population import x\n")
    (root / "reports/shared/up.py").write_text("from reports.main.page import build\n")
    (root / "reports/main/side.py").write_text("import reports.simulate.page\n")
    (root / "stages/evaluate.py").write_text("from stages.data import extra_key\nfrom stages.framework.runner import ok\n")
    (root / "stages/framework/up.py").write_text("from stages.evaluate import run\n")
    assert room_violations(root) == [
        "pipeline/evaluation/metrics/up.py:1 imports pipeline.evaluation.grid.population "
        "(evaluation.metrics may import no other room)",
        "reports/main/side.py:1 imports reports.simulate.page (a report page imports reports.shared only)",
        "reports/shared/up.py:1 imports reports.main.page (a report page imports reports.shared only)",
        "stages/evaluate.py:1 imports stages.data (a stage imports stages.framework only)",
        "stages/framework/up.py:1 imports stages.evaluate (the framework names stages by string)",
    ]
    (root / "stages/report.py").write_text("def f():\n    from stages.framework.runner import _manifest\n")
    assert private_name_violations(root) == ["stages/report.py:2 imports stages.framework.runner._manifest"]


def loader_violations(root: Path) -> list[str]:
    """loaders/ importing a part of pipeline/ other than the plumbing and the scene geometry (the
    evaluation protocol sits above the dataset floor in meaning, if not in the package order)."""
    bad = []
    for path, imports in _imports_by_module(root, "loaders"):
        for line, mod in imports:
            parts = mod.split(".")
            if parts[0] == "pipeline" and (len(parts) < 2 or parts[1] not in LOADER_SUBPACKAGES):
                bad.append(f"{path.relative_to(root)}:{line} imports {mod} "
                           f"(loaders may import pipeline.{{{', '.join(sorted(LOADER_SUBPACKAGES))}}} only)")
    return bad


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(root: Path) -> dict[str, set[str]]:
    """{module: project modules it imports}, also inside functions; ``from a.b import c`` is an
    arrow to ``a.b.c`` when that is a module, else to ``a.b``, and to the packages above it that
    the import runs (``a/__init__.py``, ``a/b/__init__.py``)."""
    paths = {_module_name(root, p): p for floor in FLOORS for p in sorted((root / floor).rglob("*.py"))}
    graph: dict[str, set[str]] = {m: set() for m in paths}
    for mod, path in paths.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in paths else node.module
                           for a in node.names]
            else:
                continue
            for t in targets:
                # importing a.b.c first runs the packages a/ and a/b/ that hold it: an arrow to each
                # (but to the importer's own packages, which are running already)
                parts = t.split(".")
                for i in range(1, len(parts) + 1):
                    up = ".".join(parts[:i])
                    if up in paths and up != mod and not mod.startswith(up + "."):
                        graph[mod].add(up)
    return graph


def import_circles(root: Path) -> list[list[str]]:
    """Groups of modules that import each other, directly or around a circle (strongly connected
    components of the import graph with more than one module), each sorted."""
    graph = import_graph(root)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    for start in sorted(graph):  # iterative Tarjan: no recursion limit on long chains
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on.add(start)
        while work:
            node, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                elif nxt in on:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    m = stack.pop()
                    on.discard(m)
                    group.append(m)
                    if m == node:
                        break
                if len(group) > 1:
                    out.append(sorted(group))
    return sorted(out)


def test_loaders_do_not_import_the_evaluation_protocol():
    bad = loader_violations(ROOT)
    assert not bad, "loaders importing above the scene geometry:\n" + "\n".join(bad)


def test_no_import_circles():
    circles = import_circles(ROOT)
    assert not circles, "modules importing each other:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_the_loader_and_circle_checks_catch_planted_violations(tmp_path):
    root = _plant(tmp_path, "scene", "")
    (root / "loaders" / "reader.py").write_text(
        "from pipeline.scene import planted\nfrom pipeline.evaluation.grid.location import locate\n")
    assert loader_violations(root) == [
        "loaders/reader.py:2 imports pipeline.evaluation.grid.location "
        "(loaders may import pipeline.{infra, method, scene} only)"]
    (root / "pipeline" / "infra" / "a.py").write_text("from pipeline.infra import b\n")
    (root / "pipeline" / "infra" / "b.py").write_text("def f():\n    import pipeline.infra.c\n")
    (root / "pipeline" / "infra" / "c.py").write_text("from pipeline.infra.a import x\n")
    assert import_circles(root) == [["pipeline.infra.a", "pipeline.infra.b", "pipeline.infra.c"]]
    (root / "pipeline" / "infra" / "c.py").write_text("x = 1\n")
    assert import_circles(root) == []


def unlisted_rooms(root: Path) -> list[str]:
    """Packages under the four floors that the room map (docs/design.md, "Where things are") names
    neither by path (``pipeline/scene/``, or a room inside it) nor as ``(+ `name/`)`` of a row."""
    import re

    text = (root / "docs" / "design.md").read_text()
    table = text.split("### Where things are", 1)[1].split("\n#", 1)[0]
    tokens = set(re.findall(r"`([^`]+)`", table))
    bad = []
    for floor in FLOORS:
        for init in sorted((root / floor).rglob("__init__.py")):
            rel = init.parent.relative_to(root).as_posix()
            if not any(t == f"{rel}/" or t.startswith(f"{rel}/") for t in tokens) and f"{init.parent.name}/" not in tokens:
                bad.append(rel)
    return bad


def test_the_readme_room_table_lists_every_room():
    bad = unlisted_rooms(ROOT)
    assert not bad, "rooms missing from docs/design.md's room map (Where things are):\n" + "\n".join(bad)


def test_the_room_table_check_catches_a_missing_room(tmp_path):
    for d in ("pipeline/scene", "pipeline/infra/config", "loaders/real_imagery", "stages", "reports"):
        (tmp_path / d).mkdir(parents=True, exist_ok=True)
        (tmp_path / d / "__init__.py").write_text("")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "design.md").write_text("# x\n### Where things are\n| `pipeline/scene/` | a |\n"
                                                 "| `pipeline/infra/` (+ `config/`) | b |\n## Next\n`loaders/real_imagery/`\n")
    assert unlisted_rooms(tmp_path) == ["loaders/real_imagery", "reports", "stages"]
