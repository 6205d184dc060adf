"""The CLI says when the code it runs is another checkout's than the one it is started in (a
project copied with its venv); a checkout first on PYTHONPATH runs silently."""
from __future__ import annotations

import os
import subprocess
import sys

from stages.framework.checkout import checkout_of, other_checkout
from tests.conftest import ROOT


def _checkout(folder):
    for d in ("stages", "pipeline", "deep/er"):
        (folder / d).mkdir(parents=True, exist_ok=True)
    (folder / "pyproject.toml").write_text('[project]\nname = "viewfuse"\n')
    return folder


def test_this_checkout_is_the_one_that_runs():
    assert checkout_of(ROOT / "pipeline" / "infra") == ROOT.resolve()
    assert other_checkout(ROOT) is None and other_checkout(ROOT / "docs") is None


def test_a_copied_checkout_is_named(tmp_path):
    copy = _checkout(tmp_path / "copy")
    msg = other_checkout(copy / "deep" / "er")
    assert msg is not None and str(copy.resolve()) in msg and str(ROOT) in msg and "make" in msg
    assert other_checkout(tmp_path) is None                       # not inside any checkout
    other = tmp_path / "other"
    _checkout(other)
    (other / "pyproject.toml").write_text('[project]\nname = "something_else"\n')
    assert other_checkout(other) is None                          # another project's folder


def test_the_cli_warns_from_inside_another_checkout_and_not_from_its_own(tmp_path):
    copy = _checkout(tmp_path / "copy")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "stages.commands.cli", "status", "--config", str(ROOT / "configs" / "smoke.toml"),
            "--set", f"run.artifacts={tmp_path / 'a'}"]
    there = subprocess.run(argv, cwd=copy, env=env, capture_output=True, text=True, timeout=120)
    assert there.returncode == 0, there.stderr
    assert f"not that of the checkout you are in ({copy.resolve()})" in there.stderr
    here = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert here.returncode == 0 and "checkout you are in" not in here.stderr
