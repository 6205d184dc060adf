"""The runner only ever creates, swaps or deletes paths inside <artifacts>/<run>/, and deletes only
folders it marked as its own; an interrupted folder swap is completed, not recomputed."""
from __future__ import annotations

import dataclasses
import os
import shutil

import pytest

import stages.framework.runner as runner
from pipeline.infra.config import ConfigError
from stages.commands.cli import main
from tests.support import stage_fakes

BAD_NAMES = ["../victim", "../../victim", "/tmp/victim", "a/b", "..", ".", ".hidden", "a\x00b", "", "x" * 200]


def plant_victim(tmp_path):
    """A folder beside the artifacts folder with a stage-named folder and a hidden '.old' one."""
    victim = tmp_path / "victim"
    (victim / "simulate").mkdir(parents=True)
    (victim / "simulate" / "keep.txt").write_text("x")
    (victim / ".precious.old").mkdir()
    (victim / ".precious.old" / "keep.txt").write_text("y")
    return victim


def victim_intact(victim) -> bool:
    return ((victim / "simulate" / "keep.txt").read_text() == "x"
            and (victim / ".precious.old" / "keep.txt").read_text() == "y")


@pytest.mark.parametrize("name", BAD_NAMES)
def test_run_name_must_be_one_plain_folder_name(tmp_config, name):
    with pytest.raises(ConfigError, match="'run.name'"):
        tmp_config({"run": {"name": name}})


def test_no_run_name_reaches_a_folder_beside_the_artifacts(tmp_path, capsys):
    victim = plant_victim(tmp_path)
    art = tmp_path / "artifacts"
    for name in ("../victim", str(victim), "../victim/.", "victim/../../victim"):
        rc = main(["simulate", "--set", f"run.artifacts={art}", "--set", f"run.name={name!r}".replace("'", '"'),
                   "--set", "simulate.realizations=5"])
        assert rc == 2, name
        assert "'run.name'" in capsys.readouterr().err
        assert victim_intact(victim)


def test_a_name_that_bypassed_the_config_check_is_still_refused(tmp_config, tmp_path, monkeypatch):
    calls = stage_fakes.install(monkeypatch, {"simulate": ()})
    victim = plant_victim(tmp_path)
    cfg = tmp_config()
    bad = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, name="../victim"))
    with pytest.raises(ConfigError, match="run.name"):
        runner.ensure(bad, "simulate")
    with pytest.raises(ConfigError):
        runner.remove_orphans(bad)
    assert calls == [] and victim_intact(victim)


def test_a_run_folder_that_is_a_symlink_is_refused(tmp_config, tmp_path, monkeypatch):
    calls = stage_fakes.install(monkeypatch, {"simulate": ()})
    victim = plant_victim(tmp_path)
    cfg = tmp_config()
    cfg.artifacts_dir.mkdir(parents=True)
    os.symlink(victim, cfg.run_dir)
    with pytest.raises(RuntimeError, match="symlink"):
        runner.ensure(cfg, "simulate")
    assert calls == [] and victim_intact(victim)


def test_orphan_clean_up_removes_only_marked_or_empty_stage_folders(tmp_config):
    cfg = tmp_config()
    run = cfg.run_dir
    run.mkdir(parents=True)
    (run / ".precious.old").mkdir()                     # not a stage's name: never touched
    (run / ".precious.old" / "keep.txt").write_text("y")
    foreign = run / ".features.old"                     # a stage's name, but not ours (no marker)
    foreign.mkdir()
    (foreign / "keep.txt").write_text("z")
    dead = run / ".models.tmp"                          # ours, its writer is dead
    (dead / "sub").mkdir(parents=True)
    (dead / runner.OWNER).write_text("999999999")
    empty = run / ".data.tmp"                           # empty: removing it cannot lose anything
    empty.mkdir()
    removed = runner.remove_orphans(cfg)
    assert sorted(p.name for p in removed) == [".data.tmp", ".models.tmp"]
    assert (run / ".precious.old" / "keep.txt").read_text() == "y"
    assert (foreign / "keep.txt").read_text() == "z"


def test_a_foreign_folder_in_the_way_of_a_stage_is_an_error_not_deleted(tmp_config, monkeypatch):
    calls = stage_fakes.install(monkeypatch, {"a": ()})
    cfg = tmp_config()
    tmp = cfg.run_dir / ".a.tmp"
    tmp.mkdir(parents=True)
    (tmp / "keep.txt").write_text("mine")
    with pytest.raises(RuntimeError, match="not created by viewfuse"):
        runner.ensure(cfg, "a")
    assert (tmp / "keep.txt").read_text() == "mine" and calls == []


def _interrupt_swap(cfg, stage, finished_tmp: bool):
    """The state a kill between the swap's two renames leaves: the previous output moved to
    .<stage>.old (marked), the new complete output still in .<stage>.tmp, no stage folder."""
    final = cfg.stage_dir(stage)
    old, tmp = final.with_name(f".{stage}.old"), final.with_name(f".{stage}.tmp")
    shutil.copytree(final, tmp)
    (tmp / runner.OWNER).write_text("999999999")
    if not finished_tmp:
        (tmp / "manifest.json").unlink()
    (final / runner.OWNER).write_text("999999999")
    os.replace(final, old)
    return old, tmp


@pytest.mark.parametrize("finished_tmp", [True, False])
@pytest.mark.parametrize("via_cleanup", [True, False])
def test_an_interrupted_swap_is_completed_not_recomputed(tmp_config, monkeypatch, capsys, finished_tmp, via_cleanup):
    calls = stage_fakes.install(monkeypatch, {"a": ()})
    cfg = tmp_config()
    runner.ensure(cfg, "a")
    before = runner.read_manifest(cfg, "a")
    old, tmp = _interrupt_swap(cfg, "a", finished_tmp)
    if via_cleanup:  # what the CLI does first
        runner.remove_orphans(cfg)
    runner.ensure(cfg, "a")
    assert calls == ["a"]                                   # not recomputed
    assert runner.read_manifest(cfg, "a") == before
    assert not old.exists() and not tmp.exists()
    assert not (cfg.stage_dir("a") / runner.OWNER).exists()
    out = capsys.readouterr().out
    assert ("finished the output swap" if finished_tmp else "restored the previous output") in out
