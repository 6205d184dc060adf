"""Stage caching checks contents: changed outputs and inputs, upstream reruns, model files against
their index, orphan temporary folders, and stage keys that follow the code a stage imports."""
from __future__ import annotations

from pipeline.method.gp_files import save_bank, load_bank
import json
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def fake_chain(monkeypatch, tmp_path):
    """a -> b; a writes out.txt (its text settable) and reads an input file (note_read)."""
    import stages.framework.registry as registry
    import stages.framework.runner as runner
    from pipeline.infra.cache import note_read
    from stages.framework.registry import StageSpec

    calls, state = [], {"text": "a1"}
    src = tmp_path / "input.bin"
    src.write_bytes(b"input v1")

    def mod(name, body):
        m = types.ModuleType(f"fake_hard_{name}")
        m.run = body
        monkeypatch.setitem(sys.modules, m.__name__, m)

    def run_a(ctx):
        calls.append("a")
        note_read(src, src.read_bytes())
        (ctx.out / "out.txt").write_text(state["text"])
        return "a"

    def run_b(ctx):
        calls.append("b")
        (ctx.out / "copy.txt").write_text((ctx.input("a") / "out.txt").read_text())
        return "b"

    mod("a", run_a), mod("b", run_b)
    specs = {"a": StageSpec("a", "fake_hard_a", (), ("features",)),
             "b": StageSpec("b", "fake_hard_b", ("a",), ("models",))}
    monkeypatch.setattr(runner, "STAGES", specs)
    monkeypatch.setattr(registry, "STAGES", specs)
    from pipeline.infra import outputs
    for s, f in (("a", "out.txt"), ("b", "copy.txt")):
        monkeypatch.setitem(outputs.CATALOG, s, {"out": outputs.Artifact(f, "text", "tests.stages.framework.test_caching:fake_chain", None)})
    return calls, state, src


def test_changed_output_reruns_and_says_which_file(tmp_config, fake_chain, capsys):
    from stages.framework.runner import ensure, plan

    calls, _, _ = fake_chain
    cfg = tmp_config()
    ensure(cfg, "b")
    assert plan(cfg, "b")["state"] == "up to date"
    out = cfg.stage_dir("a") / "out.txt"
    out.write_text("tampered")                    # bytes of an upstream output changed
    st = plan(cfg, "a")
    assert st["state"] == "stale" and str(out) in st["why"] and "content changed" in st["why"]
    assert plan(cfg, "b")["state"] == "stale"      # and everything downstream
    calls.clear()
    capsys.readouterr()
    ensure(cfg, "b")
    # a reruns and writes the same bytes again, so b's inputs are what b was built from
    assert calls == ["a"]
    assert f"output {out}" in capsys.readouterr().out
    assert out.read_text() == "a1" and plan(cfg, "b")["state"] == "up to date"


def test_forced_upstream_rerun_with_new_results_makes_downstream_stale(tmp_config, fake_chain):
    from stages.framework.runner import ensure, plan

    calls, state, _ = fake_chain
    cfg = tmp_config()
    ensure(cfg, "b")
    state["text"] = "a2"                           # e.g. evaluate --force gives other numbers
    ensure(cfg, "a", force=True)
    assert plan(cfg, "b")["state"] == "stale"
    calls.clear()
    ensure(cfg, "b")
    assert calls == ["b"] and (cfg.stage_dir("b") / "copy.txt").read_text() == "a2"
    calls.clear()
    ensure(cfg, "a", force=True)                   # same bytes again: downstream stays valid
    ensure(cfg, "b")
    assert calls == ["a"]


def test_input_rewritten_in_place_is_detected(tmp_config, fake_chain, capsys):
    from stages.framework.runner import ensure, read_manifest

    calls, _, src = fake_chain
    cfg = tmp_config()
    ensure(cfg, "a")
    assert str(src) in read_manifest(cfg, "a")["inputs"]
    src.write_bytes(b"input v2")
    calls.clear()
    capsys.readouterr()
    ensure(cfg, "a")
    assert calls == ["a"] and f"input {src}" in capsys.readouterr().out
    os.utime(src)                                  # touched, same bytes: still up to date
    calls.clear()
    ensure(cfg, "a")
    assert calls == []


def test_an_input_edited_with_its_mtime_restored_is_detected(tmp_config, fake_chain, monkeypatch):
    """Same size, same mtime, other bytes: the ctime moved, so the digest is taken again; an
    unchanged input is not reread (its digest is memoised in the run folder)."""
    from pipeline.infra import cache
    from stages.framework.runner import INPUT_MEMO, ensure, plan

    calls, _, src = fake_chain
    cfg = tmp_config()
    ensure(cfg, "a")
    assert (cfg.run_dir / INPUT_MEMO).is_file()
    hashed = []
    real_sha = cache.sha256_file
    monkeypatch.setattr(cache, "sha256_file", lambda p, *a: hashed.append(str(p)) or real_sha(p, *a))
    assert plan(cfg, "a")["state"] == "up to date" and str(src) not in hashed
    st = os.stat(src)
    src.write_bytes(b"input v9")                   # same size as "input v1"
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
    state = plan(cfg, "a")
    assert state["state"] == "stale" and state["why"] == f"input {src} content changed (sha256 differs)"
    calls.clear()
    ensure(cfg, "a")
    assert calls == ["a"]


def test_inputs_under_a_dataset_root_are_found_again_after_a_move(tmp_config, fake_chain, tmp_path):
    """Input records name files relative to their dataset root: the dataset copied elsewhere (new
    path and mtime, same bytes) with its root setting moved keeps the stage up to date."""
    import shutil

    from stages.framework.runner import ensure, plan, read_manifest

    calls, _, src = fake_chain
    ensure(tmp_config({"data": {"coil_root": str(tmp_path)}}), "a")
    assert list(read_manifest(tmp_config(), "a")["inputs"]) == ["data.coil_root:input.bin"]
    moved = tmp_path / "moved" / "input.bin"
    moved.parent.mkdir()
    shutil.copyfile(src, moved)
    os.utime(moved, ns=(9, 9))
    src.unlink()
    calls.clear()
    ensure(tmp_config({"data": {"coil_root": str(moved.parent)}}), "a")
    assert calls == []
    moved.write_bytes(b"input v3")
    state = plan(tmp_config({"data": {"coil_root": str(moved.parent)}}), "a")
    assert state["state"] == "stale" and state["why"].startswith(f"input {moved} content changed")


def test_swapped_model_files_are_an_error_naming_both(tmp_path):
    from pipeline.method.gp import ModelFileError
    from tests.pipeline.method.test_gp import make_models

    m = make_models(np.random.default_rng(0))
    save_bank(m, tmp_path)
    index = json.loads((tmp_path / "index.json").read_text())
    a, b = (tmp_path / index["files"][c] for c in m.classes[:2])
    da, db = a.read_bytes(), b.read_bytes()
    a.write_bytes(db), b.write_bytes(da)
    with pytest.raises(ModelFileError) as e:
        load_bank(tmp_path)
    assert str(a) in str(e.value) and str(b) in str(e.value) and "swapped" in str(e.value)
    a.write_bytes(da[:-10] + b"0123456789")
    with pytest.raises(ModelFileError, match="content differs from the sha256 recorded"):
        load_bank(tmp_path)


def test_orphan_temp_folders_are_removed_at_the_next_run(tmp_config):
    from stages.framework.runner import remove_orphans

    cfg = tmp_config()
    cfg.run_dir.mkdir(parents=True)
    dead = cfg.run_dir / ".features.tmp"
    (dead / "sub").mkdir(parents=True)
    (dead / ".owner").write_text("999999999")      # no such process
    bare = cfg.run_dir / ".models.tmp"
    bare.mkdir()
    live = cfg.run_dir / ".evaluate.tmp"
    live.mkdir()
    (live / ".owner").write_text(str(os.getppid()))  # a running process is still writing it
    removed = remove_orphans(cfg)
    assert sorted(p.name for p in removed) == [".features.tmp", ".models.tmp"]
    assert not dead.exists() and not bare.exists() and live.exists()


def test_stage_code_dependencies_follow_the_imports():
    from stages.framework.registry import STAGES, code_deps

    deps = {n: set(code_deps(s.module)) for n, s in STAGES.items()}
    # the modules the hand-written lists missed (reports.results_io is now reports.shared.artifacts)
    assert {"reports.shared.artifacts", "reports.simulate.findings", "pipeline.infra.cache"} <= deps["simulate"]
    assert {"stages.framework.roots", "loaders.avd"} <= deps["evaluate"]
    assert "stages.data" not in deps["evaluate"]  # no stage imports another (tests/test_layout.py)
    assert "pipeline.infra.cache" in deps["models"]
    # imports inside functions count too (stages.data imports the writers lazily)
    assert "loaders.synthetic.avd_writer" in deps["data"]
    assert all(d.split(".")[0] in ("pipeline", "loaders", "stages", "reports") for ds in deps.values() for d in ds)


def test_editing_an_imported_module_changes_the_stage_key(tmp_path, monkeypatch):
    import stages.framework.registry as registry

    pkg = tmp_path / "reports"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "zz_leaf.py").write_text("X = 1\n")
    (pkg / "zz_top.py").write_text("def f():\n    from reports import zz_leaf\n    return zz_leaf.X\n")
    monkeypatch.setattr(registry, "_module_file", lambda n: {
        "reports": pkg / "__init__.py", "reports.zz_leaf": pkg / "zz_leaf.py",
        "reports.zz_top": pkg / "zz_top.py"}.get(n))
    spec = registry.StageSpec("zz", "reports.zz_top")
    assert registry.code_deps("reports.zz_top") == ("reports", "reports.zz_leaf", "reports.zz_top")
    before = registry.code_version(spec)[0]
    # What the code says about itself (comments, docstrings, blank lines) does not change the key ...
    (pkg / "zz_leaf.py").write_text('"""A leaf module."""\n\n# the value\nX = 1  # one\n')
    assert registry.code_version(spec)[0] == before
    # ... what it does does.
    (pkg / "zz_leaf.py").write_text("X = 2\n")
    assert registry.code_version(spec)[0] != before
    (pkg / "zz_leaf.py").write_text('X = 1\ndef f():\n    """doc"""\n    return "doc"\n')
    changed = registry.code_version(spec)[0]
    (pkg / "zz_leaf.py").write_text('X = 1\ndef f():\n    """other doc"""\n    return "other"\n')
    assert registry.code_version(spec)[0] != changed  # a string that is not a docstring counts
