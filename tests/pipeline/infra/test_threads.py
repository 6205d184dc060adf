"""Threads that follow the machine (pipeline/infra/threads.py): the count from the others' CPU
time, at least one, at most the cores; passive waiting set before torch, never over the user's."""
from __future__ import annotations

import os
import subprocess
import sys

from pipeline.infra import threads


def test_free_cores_are_the_rest_of_the_machine_at_least_one_at_most_ours():
    assert threads.free_from(2, 2, 0.0) == 2
    assert threads.free_from(2, 2, 0.9) == 1      # 1.1 free rounds to 1
    assert threads.free_from(2, 2, 0.4) == 2      # 1.6 free rounds to 2
    assert threads.free_from(2, 2, 12.0) == 1     # fully loaded: one thread, never zero
    assert threads.free_from(4, 16, 3.0) == 4     # a big machine: at most the cores we may use
    assert threads.free_from(4, 16, 14.0) == 2


def test_pace_sets_the_count_the_watch_measures_from_the_others_cpu_time(monkeypatch):
    # Fake /proc/stat: every second the others add 100 busy jiffies (one core at 100 Hz), this
    # process none; then the others stop.
    clock = {"t": 0.0, "busy": 0.0, "total": 0.0}
    monkeypatch.setattr(threads.time, "monotonic", lambda: clock["t"])
    monkeypatch.setattr(threads.time, "process_time", lambda: 0.0)
    monkeypatch.setattr(threads, "_jiffies", lambda: (clock["busy"], 0.0, clock["total"]))
    monkeypatch.setattr(threads.os, "sysconf", lambda name: 100)
    monkeypatch.setattr(threads.os, "cpu_count", lambda: 2)
    seen: list[int] = []
    with threads.following_cores(2, seen.append, interval_s=1.0) as watch:
        threads.pace()                 # no interval measured yet: every core
        for busy_per_s in (100, 100, 200, 0):
            clock["t"] += 1.0
            clock["busy"] += busy_per_s
            clock["total"] += 200
            threads.pace()
    assert seen == [2, 1, 2]          # set only when it changes: 2, one core taken, both, none
    assert watch.counts == {1: 3, 2: 1}
    threads.pace()                     # outside the block: a no-op
    assert seen == [2, 1, 2]


def test_niced_time_counts_as_free_for_a_process_at_nice_0(monkeypatch):
    clock = {"t": 0.0, "nice": 0.0}
    monkeypatch.setattr(threads.time, "monotonic", lambda: clock["t"])
    monkeypatch.setattr(threads.time, "process_time", lambda: 0.0)
    monkeypatch.setattr(threads, "_jiffies", lambda: (0.0, clock["nice"], 0.0))
    monkeypatch.setattr(threads.os, "sysconf", lambda name: 100)
    monkeypatch.setattr(threads.os, "cpu_count", lambda: 2)
    for own_nice, expect in ((0, 2), (19, 1)):
        monkeypatch.setattr(threads, "_own_nice", lambda n=own_nice: n)
        w = threads.CoreWatch(2, interval_s=1.0)
        clock["t"] += 1.0
        clock["nice"] += 200        # a nice-19 hog on both cores
        assert w.threads() == expect


def test_passive_waiting_is_set_before_torch_and_never_over_the_users_choice():
    code = ("import os, pipeline, sys; import torch; "
            "print(os.environ['GOMP_SPINCOUNT'], os.environ['KMP_BLOCKTIME'])")
    env = {k: v for k, v in os.environ.items() if k not in threads.PASSIVE_ENV}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["0", "0"]
    out = subprocess.run([sys.executable, "-c", code], env={**env, "GOMP_SPINCOUNT": "1000"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1000", "0"]
