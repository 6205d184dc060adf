"""Cache keys hold content digests, never absolute paths or mtimes: a moved project (its weights
file copied, new mtime) keeps the classifier up to date; changed bytes rerun it. And ``make``
notices a venv that no longer runs."""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from tests.conftest import ROOT


def _project(folder, weights: bytes):
    """A project folder: a config extending the default with weights = path (relative)."""
    folder.mkdir()
    (folder / "w.npz").write_bytes(weights)
    cfg = folder / "c.toml"
    cfg.write_text(f'extends = "{ROOT / "configs" / "synthetic.toml"}"\n[run]\nartifacts = "artifacts"\n'
                   '[classifier]\nweights = "path"\npath = "w.npz"\n')
    return cfg


def _key(cfg_path):
    from pipeline.infra.config import load_config
    from stages.framework.registry import STAGES
    from stages.framework.runner import stage_key

    cfg = load_config(cfg_path)
    return stage_key(cfg, STAGES["classifier"], {})[0]


def test_a_moved_project_keeps_the_classifier_key(tmp_path):
    a = _project(tmp_path / "one", b"weights-bytes" * 100)
    key = _key(a)
    shutil.copytree(tmp_path / "one", tmp_path / "two")          # copy: new inode and mtime
    os.utime(tmp_path / "two" / "w.npz", ns=(1, 1))
    assert _key(tmp_path / "two" / "c.toml") == key
    shutil.rmtree(tmp_path / "one")                              # the original gone: still the same
    assert _key(tmp_path / "two" / "c.toml") == key


@pytest.mark.parametrize("change", ["one byte", "same size"])
def test_changed_weights_change_the_key(tmp_path, change):
    a = _project(tmp_path / "one", b"weights-bytes" * 100)
    key = _key(a)
    data = bytearray((tmp_path / "one" / "w.npz").read_bytes())
    data[-1] ^= 1
    st = os.stat(tmp_path / "one" / "w.npz")
    (tmp_path / "one" / "w.npz").write_bytes(bytes(data) if change == "same size" else bytes(data) + b"x")
    os.utime(tmp_path / "one" / "w.npz", ns=(st.st_atime_ns, st.st_mtime_ns))  # mtime restored
    from stages import classifier
    classifier._digests.clear()  # a new process: no memo
    assert _key(a) != key


def test_the_key_names_no_path_or_mtime(tmp_path):
    from pipeline.infra.config import load_config
    from stages.classifier import extra_key

    a = _project(tmp_path / "one", b"abc")
    k = extra_key(load_config(a))
    assert k.startswith("sha256:") and str(tmp_path) not in k and str(os.stat(tmp_path / "one" / "w.npz").st_mtime_ns) not in k


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
@pytest.mark.parametrize("shebang", ["#!/nonexistent/old/.venv/bin/python", "#!{python}"])
def test_make_rebuilds_a_venv_that_no_longer_runs(tmp_path, shebang):
    shutil.copy(ROOT / "Makefile", tmp_path)
    (tmp_path / "pyproject.toml").write_text("")
    bin_ = tmp_path / ".venv" / "bin"
    bin_.mkdir(parents=True)
    (bin_ / "python").symlink_to(shutil.which("python3"))
    (bin_ / "viewfuse").write_text(shebang.format(python=bin_ / "python") + "\n")
    (tmp_path / ".venv" / ".installed").touch()
    out = subprocess.run(["make", "-n", "venv"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    broken = "nonexistent" in shebang
    assert ("no longer runs" in out.stdout) == broken
    assert (tmp_path / ".venv").exists() != broken
    assert ("install" in out.stdout) == broken, out.stdout
