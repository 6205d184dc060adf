"""The evaluate stage gives the same files whether its cells and planning episodes run in this
process (run.threads = 1) or in two forked workers (run.threads = 2, ``LocalPool``), on the smoke
run's upstream: results.parquet, planning.parquet, the arrays and the summary (less its timings)
byte for byte."""
from __future__ import annotations

import hashlib
import json

import pytest

from tests.support.shared_upstream import DEVICE, copy_upstream, smoke_config, smoke_upstream

pytestmark = pytest.mark.slow  # builds (or reuses) the smoke upstream, then two evaluate runs


def _evaluate(tmp_path_factory, threads: int):
    from pipeline.infra import tasks
    from stages.framework.runner import ensure

    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path_factory.mktemp(f"threads{threads}"))
    cfg = smoke_config(art, {"run": {"threads": threads}})
    del tasks.STATS[:]
    ensure(cfg, "evaluate", device=DEVICE)
    return cfg.stage_dir("evaluate"), [dict(r) for r in tasks.STATS]


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
