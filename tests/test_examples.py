"""examples/ run as a user runs them (a fresh interpreter), so they cannot rot; and the public
``viewfuse`` package is what the installed project exposes."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


def _run(args, cwd, env_extra=None, timeout=900):
    env = {**os.environ, "OMP_NUM_THREADS": "2", **(env_extra or {})}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def test_there_are_examples():
    assert {p.name for p in EXAMPLES} >= {"fuse_arrays.py", "custom_method.py", "custom_classifier.py"}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path, tmp_path):
    r = _run([str(path)], cwd=tmp_path, env_extra={"PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr[-3000:]
    assert "P(final)" in r.stdout or "95 % CI" in r.stdout, r.stdout
    if path.name == "custom_classifier.py":   # registered by the script: listed after the built-ins
        assert "classifiers: alexnet, efficientnet_lite0, " in r.stdout
        assert "mobilenet_small_example\n" in r.stdout, r.stdout


def test_custom_method_example_reaches_the_comparison(tmp_path):
    r = _run([str(ROOT / "examples" / "custom_method.py")], cwd=tmp_path, env_extra={"PYTHONPATH": str(ROOT)})
    assert "majority_vote " in r.stdout and "with_uncertainty vs majority_vote" in r.stdout, r.stdout + r.stderr[-2000:]
    # registered at the top of the script, before the built-ins loaded: listed after them all
    order = next(line for line in r.stdout.splitlines() if line.startswith("methods in order:"))
    keys = order.partition(":")[2].replace(" ", "").split(",")
    assert keys[0] == "with_uncertainty" and keys[-1] == "majority_vote", order


def test_the_installed_environment_imports_viewfuse_from_anywhere(tmp_path):
    """From a folder outside the repository, without PYTHONPATH: the environment's install (make
    venv: pip install -e .) provides ``viewfuse`` and its internal packages, all from this tree."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    code = ("import viewfuse, pipeline, reports, loaders, stages; from viewfuse._check import collisions; "
            "print(viewfuse.__file__); print(pipeline.__file__); print(collisions())")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, ("viewfuse is not importable from the environment; reinstall it (make venv): "
                               + r.stderr[-2000:])
    lines = r.stdout.splitlines()
    assert Path(lines[0]).resolve().is_relative_to(ROOT / "viewfuse")
    assert Path(lines[1]).resolve().is_relative_to(ROOT / "pipeline")
    assert lines[2] == "[]"


def test_a_colliding_top_level_package_is_refused(tmp_path):
    """Another project's ``pipeline`` ahead on the path: ``import viewfuse`` names it, instead of
    running with the wrong code."""
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "__init__.py").write_text("")
    r = _run(["-c", "import viewfuse"], cwd=tmp_path, env_extra={"PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"})
    assert r.returncode != 0 and "import pipeline' finds" in r.stderr and str(tmp_path) in r.stderr


def test_nothing_internal_imports_the_public_package():
    """``viewfuse`` sits above every floor: the internal packages never import it."""
    bad = []
    for floor in ("pipeline", "loaders", "reports", "stages"):
        for path in (ROOT / floor).rglob("*.py"):
            text = path.read_text()
            if "import viewfuse" in text or "from viewfuse" in text:
                bad.append(str(path.relative_to(ROOT)))
    assert not bad, bad
