"""One run per stage at a time: a second run of the same stage waits for the first (and then
finds its output up to date) instead of deleting its live temporary folder; a lock whose holder
died does not block; the orphan clean-up leaves alone the folders of a stage another process runs."""
from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import threading
import time

import stages.framework.runner as runner
from tests.support import stage_fakes

import pytest

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


def _start(fn):
    errors: list[BaseException] = []

    def body():
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - reported by the test
            errors.append(e)
    t = threading.Thread(target=body, daemon=True)
    t.start()
    return t, errors


def test_a_second_run_of_a_stage_waits_for_the_first(tmp_config, monkeypatch, capsys):
    started, release = threading.Event(), threading.Event()

    def slow(ctx):
        started.set()
        assert release.wait(20)
    calls = stage_fakes.install(monkeypatch, {"evaluate": ()}, {"evaluate": slow})
    cfg = tmp_config()
    first, err1 = _start(lambda: runner.ensure(cfg, "evaluate"))
    assert started.wait(20)
    tmp = cfg.run_dir / ".evaluate.tmp"
    assert tmp.is_dir()
    second, err2 = _start(lambda: runner.ensure(cfg, "evaluate"))
    time.sleep(1.0)
    assert second.is_alive() and tmp.is_dir()   # waiting; the live folder is untouched
    release.set()
    first.join(20), second.join(20)
    assert not err1 and not err2, (err1, err2)
    assert calls == ["evaluate"]                # the second found the first one's output
    out = capsys.readouterr().out
    assert "waiting: another viewfuse process" in out and "up to date" in out
    assert not any(p.name.startswith(".") for p in cfg.run_dir.iterdir())  # lock file gone too


def test_a_lock_left_by_a_dead_process_does_not_block(tmp_config, monkeypatch):
    calls = stage_fakes.install(monkeypatch, {"a": ()})
    cfg = tmp_config()
    cfg.run_dir.mkdir(parents=True)
    lock = cfg.run_dir / ".a.lock"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, os, sys, time\n"
        f"fd = os.open({str(lock)!r}, os.O_RDWR | os.O_CREAT)\n"
        "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, str(os.getpid()).encode())\n"
        "print('held', flush=True); time.sleep(60)\n")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
    finally:
        holder.kill()
        holder.wait()
    assert lock.exists()                        # the file stays; the kernel dropped the lock
    t, errors = _start(lambda: runner.ensure(cfg, "a"))
    t.join(20)
    assert not t.is_alive() and not errors and calls == ["a"]


def test_clean_up_skips_the_folders_of_a_stage_another_process_runs(tmp_config, monkeypatch):
    stage_fakes.install(monkeypatch, {"a": ()})
    cfg = tmp_config()
    tmp = cfg.run_dir / ".a.tmp"
    tmp.mkdir(parents=True)
    (tmp / runner.OWNER).write_text("999999999")  # even with a pid that looks dead
    fd = os.open(cfg.run_dir / ".a.lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)           # "another process" holds the stage's lock
        assert runner.remove_orphans(cfg) == [] and tmp.is_dir()
    finally:
        os.close(fd)
    assert runner.remove_orphans(cfg) == [tmp] and not tmp.exists()
