"""Repository rules: test-only helpers live in tests/, comments cite files inside the repository."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_test_only_helpers_are_not_in_the_package():
    import pipeline.scoring.mc_dropout
    import pipeline.scoring.features
    import pipeline.method.fusion
    import pipeline.evaluation.metrics.spec
    import pipeline.evaluation.simulation.scenarios
    import pipeline.evaluation.grid.track
    import pipeline.infra.executor

    assert not (ROOT / "pipeline" / "methods.py").exists()
    for mod, name in ((pipeline.scoring.mc_dropout, "full_passes_with_masks"), (pipeline.method.fusion, "fuse_with_uncertainty_sampled"),
                      (pipeline.evaluation.metrics.spec, "summary_table"), (pipeline.scoring.features, "meta_columns"),
                      (pipeline.evaluation.grid.track, "select_track"), (pipeline.evaluation.simulation.scenarios, "conditional"),
                      (pipeline.infra.executor, "preload")):
        assert not hasattr(mod, name), f"{mod.__name__}.{name}"
    import stages.framework.runner
    assert not hasattr(stages.framework.runner, "StageNotImplemented")


def test_no_citations_of_files_outside_the_repository():
    import re

    bad = []
    files = [ROOT / "README.md", *(ROOT / "configs").glob("*.toml")]
    for d in ("pipeline", "loaders", "stages", "reports", "tests"):
        files += sorted((ROOT / d).rglob("*.py"))
    outside = re.compile(r"DESIGN §|/work/shared|(?<![\w/])formats/")
    for path in files:
        for no, line in enumerate(path.read_text().splitlines(), start=1):
            if outside.search(line) and "outside = re.compile" not in line:
                bad.append(f"{path.relative_to(ROOT)}:{no}: {line.strip()}")
    assert not bad, "citations of files outside the repository:\n" + "\n".join(bad)
    for cited in ("docs/design.md", "docs/formats/avd.md", "docs/formats/bigbird.md",
                  "docs/formats/avd_instance_id_map.txt"):
        assert (ROOT / cited).is_file(), cited


PRODUCT = ("pipeline", "loaders", "stages", "reports")
# Issue numbers belong to the tracker, and a measurement's date to docs/results.md or
# docs/benchmarks.md: in code, tests, configs and the README they go stale unseen.
ISSUE = r"\bissues?[ _-]?#?\d+|(?<![\w&#:'\"])#\d{1,4}\b"
DATED = (r"\b(January|February|March|April|May|June|July|August|September|October|November|December) \d{4}\b"
         r"|\b20\d\d-[01]\d-[0-3]\d\b")
# The page checker's test feeds it an issue number to see it refused; this file plants its own.
ALLOWED = {"tests/reports/test_report_selfcheck.py", "tests/test_repository_rules.py"}


def _code_files():
    files = [ROOT / "README.md", ROOT / "Makefile", ROOT / "pyproject.toml", *(ROOT / "configs").glob("*.toml")]
    for d in (*PRODUCT, "tests", "tools"):
        files += sorted((ROOT / d).rglob("*.py"))
    return files


def stale_references(files, root: Path = ROOT) -> list[str]:
    import re

    issue, dated = re.compile(ISSUE, re.IGNORECASE), re.compile(DATED)
    bad = []
    for path in files:
        rel = path.relative_to(root).as_posix()
        if rel in ALLOWED and root == ROOT:
            continue
        for no, line in enumerate(path.read_text().splitlines(), start=1):
            if issue.search(line) or dated.search(line):
                bad.append(f"{rel}:{no}: {line.strip()}")
    return bad


def test_no_issue_numbers_or_dated_measurements_in_code_tests_or_configs():
    bad = stale_references(_code_files())
    assert not bad, "issue numbers or dates (say what the code does, not where it came from):\n" + "\n".join(bad)


def test_the_stale_reference_rule_catches_planted_ones(tmp_path):
    p = tmp_path / "m.py"
    p.write_text('x = 1  # see issue 31\ny = "#999"  # a colour\nz = 2  # fixes #12\n'
                 '# measured 140 s (December 2026)\nw = 3  # Issue-7\n')
    assert [b.split(":")[1] for b in stale_references([p], tmp_path)] == ["1", "3", "4", "5"]


def shaped_like_tests(root: Path = ROOT) -> list[str]:
    """Product modules pytest would take for tests: a test_*.py name, or a module-level
    ``test_*`` function or ``Test*`` class (collected wherever a test module imports them)."""
    import ast

    bad = []
    for d in PRODUCT:
        for path in sorted((root / d).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if path.name.startswith("test_") or path.stem.endswith("_test"):
                bad.append(f"{rel}: module named like a test")
            for node in ast.parse(path.read_text()).body:
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("test"):
                    bad.append(f"{rel}:{node.lineno}: function {node.name}")
                elif isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
                    bad.append(f"{rel}:{node.lineno}: class {node.name}")
    return bad


def test_no_product_module_is_named_or_shaped_like_a_test(tmp_path):
    bad = shaped_like_tests()
    assert not bad, "product code pytest would collect:\n" + "\n".join(bad)
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "test_x.py").write_text("class TestDomain:\n    pass\n\ndef test_variances():\n    pass\n")
    for d in PRODUCT[1:]:
        (tmp_path / d).mkdir()
    assert shaped_like_tests(tmp_path) == ["pipeline/test_x.py: module named like a test",
                                           "pipeline/test_x.py:1: class TestDomain",
                                           "pipeline/test_x.py:4: function test_variances"]


def test_tools_holds_no_one_off_migration_scripts():
    # tools/ keeps reusable helpers; a script written for one migration lives in the git history
    assert sorted(p.name for p in (ROOT / "tools").iterdir() if not p.name.startswith((".", "__"))) == \
        ["calibrate.py", "gen_docs.py", "hard_failures.py", "instance_loio.py", "peak_rss.py", "uv_flags.py",
         "vs_baseline.py"]


# The Dirichlet method lives behind its model provider: its name is in its own files and in the
# built-in methods' listing only; everything else (config, cost, grid, banks, stages, reports)
# reaches it through the method and provider registries.
DIRICHLET_OWN = {"pipeline/method/dirichlet.py", "pipeline/method/dirichlet_fusion.py",
                 "pipeline/method/methods/dirichlet.py", "pipeline/method/methods/__init__.py"}


def named_outside(word: str, own: set[str], root: Path = ROOT) -> list[str]:
    """``.py`` files of the product (and ``viewfuse/``, ``tools/``) outside ``own`` naming ``word``, any case."""
    bad = []
    for d in ("viewfuse", *PRODUCT, "tools"):
        for path in sorted((root / d).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel not in own and word in path.read_text().lower():
                bad.append(rel)
    return bad


def test_the_dirichlet_is_named_only_in_its_own_files(tmp_path):
    bad = named_outside("dirichlet", DIRICHLET_OWN)
    assert not bad, "the Dirichlet named outside its own files (declare it on its provider instead):\n" + "\n".join(bad)
    for d in ("viewfuse", *PRODUCT, "tools"):
        (tmp_path / d).mkdir()
    (tmp_path / "pipeline" / "own.py").write_text("x = 'dirichlet'\n")
    (tmp_path / "stages" / "cost.py").write_text("# the DIRICHLET posterior clouds\n")
    (tmp_path / "reports" / "page.py").write_text("x = 1\n")
    assert named_outside("dirichlet", {"pipeline/own.py"}, tmp_path) == ["stages/cost.py"]


# The class models with an instance term live behind their model provider too: the stages, the grid,
# planning, the banks, the config and the report reach them through the provider registry. Their
# identifiers stay in their own files, the methods' listing and keys, the GP layer that reads such a
# bank as one GP bank (its files and the fusion engines), the public fit_models(instances=) and its
# leave-one-instance-out judgement (pipeline/evaluation/instance_loio.py, run by tools/instance_loio.py).
INSTANCE_WORDS = ("gp_instance", "instance_term", "instance_bank", "instance_models", "instancegpclassmodels",
                  "fit_instance_models")
INSTANCE_OWN = {"pipeline/method/gp_instance.py", "pipeline/method/gp_instance_fit.py",
                "pipeline/method/gp_instance_batch.py", "pipeline/method/methods/instance_term.py",
                "pipeline/method/methods/with_uncertainty_instance.py",
                "pipeline/method/methods/model_based_instance.py", "pipeline/method/methods/__init__.py",
                "pipeline/method/names.py",
                "pipeline/method/gp_files.py", "pipeline/method/engine.py", "pipeline/method/engine_torch.py",
                "viewfuse/api.py", "pipeline/evaluation/instance_loio.py"}


def test_the_instance_term_is_named_only_in_its_own_files(tmp_path):
    bad = {w: named_outside(w, INSTANCE_OWN) for w in INSTANCE_WORDS}
    bad = {w: files for w, files in bad.items() if files}
    assert not bad, "the instance term named outside its own files (reach it through its provider):\n" + \
        "\n".join(f"{w}: {', '.join(files)}" for w, files in bad.items())
    for d in ("viewfuse", *PRODUCT, "tools"):
        (tmp_path / d).mkdir()
    (tmp_path / "stages" / "evaluate.py").write_text("banks[INSTANCE_BANK] = load_bank(d)\n")
    (tmp_path / "pipeline" / "grid.py").write_text("# the plain bank only\n")
    assert named_outside("instance_bank", set(), tmp_path) == ["stages/evaluate.py"]
