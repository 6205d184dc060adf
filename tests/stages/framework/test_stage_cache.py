"""The stage cache shared across run names (stages/framework/stage_cache.py): a stage whose key a
finished stage of any run had reuses its outputs (hard links, verified), says which run, and the
cache stays within run.stage_cache_gb, least recently used first."""
from __future__ import annotations

import os

from tests.stages.framework.test_caching import fake_chain  # noqa: F401  (the a -> b chain fixture)


def _cfg(tmp_config, name: str, gb: float = 1.0, seed: int = 0):
    # features.seed: a section of stage a's key (another seed, another entry)
    return tmp_config({"run": {"name": name, "stage_cache_gb": gb}, "features": {"seed": seed}})


def test_a_second_run_name_reuses_every_stage_and_says_from_which_run(tmp_config, fake_chain, capsys):  # noqa: F811
    from stages.commands.cli import _cache_words   # what `viewfuse status` adds to a stage's line
    from stages.framework.runner import ensure, plan, read_manifest

    def status(cfg, stage):
        s = plan(cfg, stage)
        return s["state"] + _cache_words(cfg, stage, s)

    calls, _, _ = fake_chain
    first, second = _cfg(tmp_config, "first"), _cfg(tmp_config, "second")
    ensure(first, "b")
    assert calls == ["a", "b"]
    assert "will be reused" not in capsys.readouterr().out
    assert status(second, "a") == "missing (the stage cache holds it from run 'first': it will be reused)"
    calls.clear()
    ensure(second, "b")
    assert calls == []                                       # nothing computed again
    out = capsys.readouterr().out
    assert "[a] reused from run 'first'" in out and "[b] reused from run 'first'" in out
    for stage, f in (("a", "out.txt"), ("b", "copy.txt")):
        mine, theirs = second.stage_dir(stage) / f, first.stage_dir(stage) / f
        assert mine.read_bytes() == theirs.read_bytes()
        assert not mine.is_symlink() and os.stat(mine).st_ino == os.stat(theirs).st_ino   # a hard link
        assert read_manifest(second, stage)["reused"]["run"] == "first"
        assert status(second, stage) == "up to date (reused from run 'first' through the stage cache)"


def test_a_cached_file_changed_through_its_link_is_dropped_and_the_stage_runs(tmp_config, fake_chain, capsys):  # noqa: F811
    from stages.framework.runner import ensure

    calls, _, _ = fake_chain
    first, second = _cfg(tmp_config, "first"), _cfg(tmp_config, "second")
    ensure(first, "a")
    with open(first.stage_dir("a") / "out.txt", "r+") as fh:   # in place: the cache's inode too
        fh.write("X")
    calls.clear()
    ensure(second, "a")
    assert calls == ["a"] and (second.stage_dir("a") / "out.txt").read_text() == "a1"
    assert not any(p.name.startswith("a-") and (p / "entry.json").read_text().count('"run": "first"')
                   for p in (first.artifacts_dir / ".stage-cache").iterdir())


def test_a_changed_dataset_input_is_not_reused(tmp_config, fake_chain):  # noqa: F811
    from stages.framework.runner import ensure

    calls, _, src = fake_chain
    ensure(_cfg(tmp_config, "first"), "a")
    src.write_bytes(b"input v2")          # the file stage a read: same key, other content
    calls.clear()
    ensure(_cfg(tmp_config, "second"), "a")
    assert calls == ["a"]


def test_off_at_zero_and_least_recently_used_entries_go_first(tmp_config, fake_chain):  # noqa: F811
    from stages.framework import stage_cache
    from stages.framework.runner import ensure

    _, state, _ = fake_chain
    off = _cfg(tmp_config, "off", gb=0)
    ensure(off, "b")
    assert not (off.artifacts_dir / ".stage-cache").exists()
    # room for two 8-byte files, not three
    gb = 20 / (1 << 30)
    for i, text in enumerate(("aaaaaaa1", "aaaaaaa2")):
        state["text"] = text
        ensure(_cfg(tmp_config, f"r{i}", gb, seed=i), "a")
    held = stage_cache.entries(_cfg(tmp_config, "x", gb))
    assert len(held) == 2
    os.utime(held[0][2] / "entry.json", (1, 1))   # the first is the least recently used
    state["text"] = "aaaaaaa3"
    ensure(_cfg(tmp_config, "r2", gb, seed=2), "a")
    left = stage_cache.entries(_cfg(tmp_config, "x", gb))
    assert len(left) == 2 and held[0][2] not in [d for _, _, d in left]
    assert sum(size for _, size, _ in left) <= 20


def test_a_study_seed_reuses_the_runs_finished_chain_through_the_runs_cache(tmp_config, fake_chain):  # noqa: F811
    from stages.commands.study import seed_config, study_dir
    from stages.framework import stage_cache
    from stages.framework.runner import ensure, read_manifest

    calls, _, _ = fake_chain
    run = _cfg(tmp_config, "run")
    ensure(run, "b")
    seed = seed_config(run, 0)                 # stage a's key does not hold classifier.seed
    assert seed.run_dir.parent == study_dir(run)
    assert stage_cache.root(seed) == stage_cache.root(run) == run.artifacts_dir / ".stage-cache"
    calls.clear()
    ensure(seed, "b")
    assert calls == []                         # nothing computed again for the seed
    assert read_manifest(seed, "b")["reused"]["run"] == "run"
    assert not (study_dir(run) / ".stage-cache").exists()


def test_run_stage_cache_names_another_folder(tmp_config, fake_chain, tmp_path):  # noqa: F811
    from stages.framework.runner import ensure

    calls, _, _ = fake_chain
    elsewhere = tmp_path / "shared-cache"
    first = tmp_config({"run": {"name": "first", "stage_cache": str(elsewhere), "stage_cache_gb": 1.0}, "features": {"seed": 0}})
    ensure(first, "a")
    assert any(p.name.startswith("a-") for p in elsewhere.iterdir())
    assert not (first.artifacts_dir / ".stage-cache").exists()
    calls.clear()
    ensure(tmp_config({"run": {"name": "second", "stage_cache": str(elsewhere), "stage_cache_gb": 1.0}, "features": {"seed": 0}}), "a")
    assert calls == []
