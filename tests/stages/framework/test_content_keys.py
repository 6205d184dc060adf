"""Cache keys hold content digests, never absolute paths or mtimes: a moved project (its weights
file copied, new mtime) keeps the classifier up to date; changed bytes rerun it. And ``make``
notices a venv that no longer runs."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

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


def _fake_venv(project, shebang: str, imports_from=None):
    """A project with the Makefile and an installed-looking .venv whose python imports ``stages``
    from ``imports_from`` (an editable install's mapping; default: the project itself)."""
    shutil.copy(ROOT / "Makefile", project)
    (project / "pyproject.toml").write_text("")
    (project / "stages").mkdir(exist_ok=True)
    (project / "stages" / "__init__.py").write_text("")
    bin_ = project / ".venv" / "bin"
    bin_.mkdir(parents=True)
    (bin_ / "python").write_text(f'#!/bin/sh\nPYTHONPATH="{imports_from or project}" exec "{sys.executable}" "$@"\n')
    (bin_ / "python").chmod(0o755)
    (bin_ / "viewfuse").write_text(shebang.format(python=bin_ / "python") + "\n")
    (project / ".venv" / ".installed").touch()


def _make_n(project) -> str:
    out = subprocess.run(["make", "-n", "venv"], cwd=project, capture_output=True, text=True, timeout=60,
                         env={k: v for k, v in os.environ.items() if not k.startswith("MAKE")})
    return out.stdout + out.stderr


# what pip writes instead of a shebang when the venv's path is too long for one
TRAMPOLINE = "#!/bin/sh\n'''exec' \"$(dirname -- \"$(realpath -- \"$0\")\")\"/'python' \"$0\" \"$@\"\n' '''"


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
@pytest.mark.parametrize("shebang", ["#!/nonexistent/old/.venv/bin/python", "#!{python}", TRAMPOLINE])
def test_make_rebuilds_a_venv_that_no_longer_runs(tmp_path, shebang):
    _fake_venv(tmp_path, shebang)
    out = _make_n(tmp_path)
    broken = "nonexistent" in shebang
    assert ("no longer runs" in out) == broken, out
    assert "another checkout" not in out
    assert (tmp_path / ".venv").exists() != broken
    assert ("install" in out) == broken, out


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
@pytest.mark.parametrize("fix_shebang", [False, True], ids=["as copied", "entry points rewritten"])
def test_make_rebuilds_a_venv_copied_from_another_checkout(tmp_path, fix_shebang):
    # cp -a of a project: the copy's venv runs (the original is still there) but the original's code
    orig, copy = tmp_path / "orig", tmp_path / "copy"
    orig.mkdir()
    _fake_venv(orig, "#!{python}")
    assert "another checkout" not in _make_n(orig)
    subprocess.run(["cp", "-a", str(orig), str(copy)], check=True)
    if fix_shebang:   # only the editable mapping still points back
        (copy / ".venv" / "bin" / "viewfuse").write_text(f"#!{copy / '.venv' / 'bin' / 'python'}\n")
    out = _make_n(copy)
    assert "belongs to another checkout" in out and "rebuilding it" in out, out
    assert (f"imports stages from {orig}" in out) == fix_shebang
    assert (f"points run {orig / '.venv' / 'bin'}/python" in out) != fix_shebang
    assert not (copy / ".venv").exists() and "install" in out
    assert (orig / ".venv" / "bin" / "viewfuse").exists()        # the original's venv untouched
    assert "another checkout" not in _make_n(orig)


# ------------------------------------------------------------------------------------------------
# data.source = "real": the data stage's key is a content fingerprint of the dataset trees.

def _real_project(folder):
    """A project with a tiny real-format dataset (relative roots): a scan, an instance map, one
    BigBIRD object with a calibration file and a view. The bytes are arbitrary: only the key is read."""
    scan = folder / "data" / "avd" / "Home_001_1"
    (scan / "jpg_rgb").mkdir(parents=True)
    for i in range(3):
        (scan / "jpg_rgb" / f"00011000{i}101.jpg").write_bytes(bytes([i]) * 300)
    (scan / "annotations.json").write_text('{"000110000101.jpg": {"bounding_boxes": []}}')
    (folder / "data" / "avd" / "instance_id_map.txt").write_text("background 0\nsyrup 1\n")
    obj = folder / "data" / "bigbird" / "syrup"
    obj.mkdir(parents=True)
    (obj / "calibration.h5").write_bytes(b"calibration" * 20)
    (obj / "NP1_0.jpg").write_bytes(b"view" * 50)
    cfg = folder / "c.toml"
    cfg.write_text(f'extends = "{ROOT / "configs" / "synthetic.toml"}"\n[run]\nartifacts = "artifacts"\n'
                   '[data]\nsource = "real"\nbigbird_root = "data/bigbird"\navd_root = "data/avd"\n'
                   'scans = ["Home_001_1"]\n')
    return cfg


def _data_key(cfg_path):
    from pipeline.infra.config import load_config
    from stages.data import extra_key

    return extra_key(load_config(cfg_path))


def _edit_keeping_mtime(path, data: bytes):
    st = os.stat(path)
    path.write_bytes(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_a_moved_or_copied_real_dataset_keeps_the_data_key(tmp_path):
    key = _data_key(_real_project(tmp_path / "one"))
    assert str(tmp_path) not in key
    shutil.copytree(tmp_path / "one", tmp_path / "two")          # new paths, inodes, mtimes
    for p in (tmp_path / "two").rglob("*"):
        os.utime(p, ns=(5, 5))
    shutil.rmtree(tmp_path / "one")
    assert _data_key(tmp_path / "two" / "c.toml") == key
    for p in (tmp_path / "two" / "data").rglob("*"):          # touched again: same bytes, same key
        os.utime(p, ns=(7, 7))
    assert _data_key(tmp_path / "two" / "c.toml") == key


@pytest.mark.parametrize("target", ["data/avd/Home_001_1/jpg_rgb/000110000101.jpg", "data/avd/instance_id_map.txt",
                                    "data/bigbird/syrup/calibration.h5", "data/avd/Home_001_1/annotations.json"])
def test_one_changed_byte_in_the_real_dataset_changes_the_data_key(tmp_path, target):
    cfg = _real_project(tmp_path / "p")
    from pipeline.infra.config import load_config

    load_config(cfg).run_dir.mkdir(parents=True)                 # the run folder: the memo is kept there
    key = _data_key(cfg)
    assert _data_key(cfg) == key                                 # the memo answers the same
    path = tmp_path / "p" / target
    data = bytearray(path.read_bytes())
    data[0] ^= 1
    _edit_keeping_mtime(path, bytes(data))                       # same size, mtime restored
    assert _data_key(cfg) != key


def test_the_digest_memo_stays_in_the_run_folder_and_spares_rereads(tmp_path, monkeypatch):
    from pipeline.infra import cache
    from pipeline.infra.config import load_config

    cfg_path = _real_project(tmp_path / "p")
    run_dir = load_config(cfg_path).run_dir
    run_dir.mkdir(parents=True)
    before = {p for p in tmp_path.rglob("*")}
    key = _data_key(cfg_path)
    assert {p for p in tmp_path.rglob("*")} - before == {run_dir / ".data.digests.json"}
    hashed = []
    real_sha = cache.sha256_file
    monkeypatch.setattr(cache, "sha256_file", lambda p, *a: hashed.append(p) or real_sha(p, *a))
    assert _data_key(cfg_path) == key and hashed == []            # a rerun reads no file
    (tmp_path / "p" / "data" / "avd" / "instance_id_map.txt").write_text("background 0\nsyrup 2\n")
    assert _data_key(cfg_path) != key and len(hashed) == 1        # only the changed file is read
