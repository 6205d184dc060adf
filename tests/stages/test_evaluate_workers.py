"""How many workers the evaluate stage's cells get; and the stage gives the same files whether its cells and planning episodes run in this
process (run.threads = 1) or in two forked workers (run.threads = 2, ``LocalPool``), on the smoke
run's upstream: results.parquet, planning.parquet, the arrays and the summary (less its timings)
byte for byte."""
from __future__ import annotations

import hashlib
import json

import pytest

from tests.support.shared_upstream import DEVICE, copy_upstream, smoke_config, smoke_upstream


def _ctx(threads=0, run_threads=0, device="cpu"):
    from types import SimpleNamespace

    from pipeline.infra.config import load_config
    from tests.conftest import DEFAULT_CONFIG

    cfg = load_config(DEFAULT_CONFIG, {"run": {"threads": run_threads}})
    return SimpleNamespace(cfg=cfg, threads=threads, device_request=device, device=device)


def test_worker_count_follows_the_threads_the_free_cores_and_the_device(monkeypatch):
    import pipeline.infra.budget as budget
    import stages.evaluate as evaluate
    from stages.evaluate import local_processes

    # the budget's own count, and the names the stage module bound at its import
    monkeypatch.setattr(budget, "cores", lambda: 4)
    monkeypatch.setattr(evaluate, "cores", lambda: 4)
    monkeypatch.setattr(evaluate, "free_cores", lambda: 3)
    assert local_processes(_ctx()) == 3                      # run.threads = 0: the free cores
    assert local_processes(_ctx(run_threads=2)) == 2
    assert local_processes(_ctx(threads=1, run_threads=2)) == 1   # --threads first
    assert local_processes(_ctx(run_threads=16)) == 4       # never more than the cores
    assert local_processes(_ctx(run_threads=2, device="cuda")) == 1   # a GPU context does not fork


def _evaluate(tmp_path_factory, threads: int):
    from pipeline.infra import tasks
    from stages.framework.runner import ensure

    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path_factory.mktemp(f"threads{threads}"))
    cfg = smoke_config(art, {"run": {"threads": threads}})
    del tasks.STATS[:]
    ensure(cfg, "evaluate", device=DEVICE)
    return cfg.stage_dir("evaluate"), [dict(r) for r in tasks.STATS]


@pytest.mark.slow  # builds (or reuses) the smoke upstream, then two evaluate runs
def test_one_and_two_worker_processes_write_the_same_files(tmp_path_factory):
    one, stats_one = _evaluate(tmp_path_factory, 1)
    two, stats_two = _evaluate(tmp_path_factory, 2)
    assert {r["slots"] for r in stats_one if r["desc"] == "evaluate: cells"} == {1}
    assert {r["slots"] for r in stats_two if r["desc"].startswith("evaluate: ")} == {2}  # really forked
    names = sorted(p.name for p in one.iterdir() if p.name != "manifest.json")
    assert names == sorted(p.name for p in two.iterdir() if p.name != "manifest.json")
    assert {"results.parquet", "planning.parquet", "summary.json", "track.json"} <= set(names)
    for name in names:
        a, b = (one / name).read_bytes(), (two / name).read_bytes()
        if name == "summary.json":
            ja, jb = json.loads(a), json.loads(b)
            ja.pop("timings_s"), jb.pop("timings_s")
            assert ja == jb, name
        else:
            assert hashlib.sha256(a).digest() == hashlib.sha256(b).digest(), name
