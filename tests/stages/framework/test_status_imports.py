"""``viewfuse status`` derives every stage's code fingerprint from the source files without
importing the packages (its speed goal is in tests/bench/bench_status.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("torch", "torchvision", "pandas", "matplotlib", "sklearn", "cv2", "h5py")


def test_status_imports_none_of_the_heavy_packages(tmp_path):
    code = ("import sys\nfrom stages.commands.cli import main\n"
            f"rc = main(['status', '--set', 'run.artifacts={tmp_path}'])\n"
            f"print('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules))\nsys.exit(rc)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr
    assert "HEAVY []" in r.stdout, r.stdout


def test_module_files_are_found_by_path_without_importing():
    import stages.framework.registry as registry

    assert registry._module_file("stages.models") == ROOT / "stages" / "models.py"
    assert registry._module_file("pipeline.infra") == ROOT / "pipeline" / "infra" / "__init__.py"
    assert registry._module_file("pipeline.nope") is None and registry._module_file("torch") is None
    assert registry.defines("stages.features", "extra_key") and registry.defines("stages.models", "extra_key") is False


def test_the_import_scan_finds_what_the_syntax_tree_holds():
    import ast

    from stages.framework.registry import PACKAGES, scan_imports

    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            text = f.read_text()
            want = set()
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, ast.Import):
                    want.update((0, a.name, ()) for a in node.names)
                elif isinstance(node, ast.ImportFrom):
                    want.add((node.level, node.module or "", tuple(a.name for a in node.names)))
            assert set(scan_imports(text)) == want, f


def test_the_import_scan_reads_every_statement_form():
    from stages.framework.registry import scan_imports

    text = ("import a.b as c, d\n  from ..x import (y,\n    z as w,  # note\n)\nfrom . import q\n"
            "def f():\n    from pipeline.infra import cache; import e\n# from not import me\n"
            "from m import \\\n    n\n")
    assert set(scan_imports(text)) == {(0, "a.b", ()), (0, "d", ()), (2, "x", ("y", "z")), (1, "", ("q",)),
                                       (0, "pipeline.infra", ("cache",)), (0, "e", ()), (0, "m", ("n",))}


def test_the_code_fingerprint_ignores_docs_and_hash_order(tmp_path):
    from stages.framework.registry import source_fingerprint

    f = tmp_path / "m.py"

    def fp(text):
        f.write_text(text)
        os.utime(f, ns=(0, len(text) * 1000 + hash(text) % 1000))  # a new (size, mtime) per version
        return source_fingerprint(f)
    body = ('def g(x):\n    """{doc}"""\n    try:  # {c}\n        return x in {{"a", "b", "c"}}\n'
            '    except TypeError:\n        return None\n')
    base = fp(body.format(doc="one", c="first"))
    assert fp(body.format(doc="another docstring, longer", c="second\n# more comment")) == base
    assert fp(body.format(doc="one", c="first").replace('"c"', '"d"')) != base
    # frozenset constants print in string-hash order, which differs between processes
    code = f"from stages.framework.registry import source_fingerprint; print(source_fingerprint({str(f)!r}))"
    f.write_text(body.format(doc="one", c="first"))
    outs = {subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONHASHSEED": seed}).stdout
            for seed in ("1", "2", "3")}
    assert len(outs) == 1 and len(outs.pop().strip()) == 64
