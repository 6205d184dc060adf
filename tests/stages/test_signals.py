"""SIGTERM ends a stage as cleanly as SIGINT, and a SIGKILLed run leaves no process writing
behind: real ``viewfuse data`` subprocesses with two render workers."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from tests.support.tiny_world import TINY

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def start(tmp_path: Path, stage: str = "data") -> subprocess.Popen:
    args = [sys.executable, "-m", "stages.commands.cli", stage, "--progress", "off", "--set", f"run.artifacts={tmp_path}"]
    if stage == "data":
        syn = {**TINY["data"]["synthetic"], "workers": 2}
        args += ["--set", f"data.scans={json.dumps(TINY['data']['scans'])}"]
        for k, v in syn.items():
            args += ["--set", f"data.synthetic.{k}={json.dumps(v)}"]
    else:  # the classifier renders its source domain in 2 processes, 250 images per task
        args += ["--set", "classifier.training.train_images=20000", "--set", "classifier.training.render_workers=2"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _cmdline(p: psutil.Process) -> list[str]:
    """A child's command line, or none for one that exited (or became a zombie) while we looked:
    a short-lived helper of the stage may end between ``children()`` and this call."""
    try:
        return p.cmdline()
    except (psutil.ZombieProcess, psutil.NoSuchProcess, psutil.AccessDenied):
        return []


def workers_of(proc: subprocess.Popen, n: int = 2, timeout: float = 60.0) -> list[psutil.Process]:
    """The pool workers (and the resource tracker) once ``n`` workers run."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        kids = psutil.Process(proc.pid).children(recursive=True)
        if sum("spawn_main" in " ".join(_cmdline(k)) for k in kids) >= n:
            return kids
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("the data stage did not start its workers")


def gone(procs: list[psutil.Process], timeout: float = 10.0) -> list[psutil.Process]:
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    return alive


@pytest.mark.parametrize("stage", ["data", "classifier"])
def test_sigterm_stops_the_workers_and_removes_the_partial_output(tmp_path, stage):
    proc = start(tmp_path, stage)
    kids = workers_of(proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "terminated (SIGTERM); partial outputs were discarded" in err
    assert not gone(kids), "pool workers or the resource tracker outlived the stage"
    run = tmp_path / "synthetic"
    assert not (run / f".{stage}.tmp").exists() and not (run / f".{stage}.workers").exists()


def test_after_sigkill_no_worker_writes_and_a_rerun_succeeds(tmp_path):
    proc = start(tmp_path)
    kids = workers_of(proc)
    proc.kill()
    proc.communicate(timeout=30)
    assert not gone(kids), "workers survived their killed parent"
    rerun = start(tmp_path)
    out, err = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, err
    run = tmp_path / "synthetic"
    assert (run / "data" / "truth.json").is_file() and not (run / ".data.tmp").exists()
    assert not (run / ".data.workers").exists()


def test_a_rerun_stops_leftover_workers_it_finds_recorded(tmp_path):
    """Without the kernel's help (another OS, a worker started before its request took effect),
    the pid file lets the next run stop what the killed one left."""
    from pipeline.infra.workers import record_line, stop_leftovers
    child = subprocess.Popen([sys.executable, "-c", "import multiprocessing, time; time.sleep(60)"])
    other = subprocess.Popen([sys.executable, "-c", "import multiprocessing, time; time.sleep(60)"])
    try:
        pids = tmp_path / ".data.workers"
        # the worker as a pool records it; this process; a pid that is gone; a live pid whose recorded
        # start is not its own (the kernel reused it for another program), and one with no start:
        # only the first is stopped
        stale = f"{other.pid} t1\n{other.pid}\n"
        pids.write_text(record_line(child.pid) + record_line(os.getpid()) + "999999999 t5\n" + stale)
        assert stop_leftovers(pids) == [child.pid]
        assert other.poll() is None
        child.wait(timeout=10)  # it would sleep 60 s: ended here means it was stopped
        assert not pids.exists()
        assert psutil.pid_exists(os.getpid())
    finally:
        child.kill()
        other.kill()
