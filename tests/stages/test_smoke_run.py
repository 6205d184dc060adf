"""The main job end to end as a new user runs it: ``viewfuse evaluate`` and ``viewfuse simulate`` on
configs/smoke.toml (the default config shrunk: every stage, every method, planning, the strict
report) through the CLI into the session's shared smoke folder (tests/support/shared_upstream.py:
the chain tests reuse its upstream stages; whichever process comes first builds each stage). The
run must exit 0 and write the page whatever the one-epoch classifier's weights came out as on this
machine."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.support.shared_upstream import DEVICE, SMOKE, smoke_artifacts

pytestmark = pytest.mark.slow  # the whole chain: make test runs it, make test-fast skips it

METHODS = {"with_uncertainty", "model_based", "simple_bayes", "dirichlet", "view_independent"}


def _viewfuse(*args: str, artifacts) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "stages.commands.cli", *args, "--config", str(SMOKE),
           "--set", f"run.artifacts={artifacts}", "--device", DEVICE, "--progress", "off"]
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")}
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    art = smoke_artifacts(tmp_path_factory)
    runs = {stage: _viewfuse(stage, artifacts=art) for stage in ("evaluate", "simulate")}
    return art / "smoke", runs


def test_the_smoke_chain_exits_0_and_writes_the_report(smoke):
    run, runs = smoke
    for stage, p in runs.items():
        assert p.returncode == 0, f"viewfuse {stage} exited {p.returncode}:\n{p.stderr[-4000:]}"
    for page in ("report/index.html", "simulate/index.html"):
        assert (run / page).is_file(), page
    html = (run / "report" / "index.html").read_text()
    assert 'class="scorecard' in html and "§5.4.1" in html     # the paper's numbers, with their section
    for stage in ("data", "classifier", "features", "models", "evaluate", "report", "simulate"):
        assert json.loads((run / stage / "manifest.json").read_text())["key"], stage


def test_the_summary_has_every_method_and_planning(smoke):
    run, _ = smoke
    ev = run / "evaluate"
    pop = json.loads((ev / "summary.json").read_text())["population"]
    assert set(pop["methods"]) == METHODS
    assert set(pop["pooled"]) >= METHODS
    assert {r["method"] for r in pop["records"]} == {"with_uncertainty"}
    assert {r["baseline"] for r in pop["records"]} == METHODS - {"with_uncertainty"}
    assert "attribution" in pop["ablations"] and pop["n_targets"] >= 3
    assert (ev / "planning.parquet").is_file()


def test_the_card_names_the_machine_the_numbers_came_from(smoke):
    run, _ = smoke
    card = json.loads((run / "classifier" / "card.json").read_text())
    fp = card["determinism"]
    assert fp["cpu_model"] and fp["torch_threads"] >= 1 and fp["versions"]["torch"]
    assert "cpu_capability" in fp and ("torch_blas_info" in fp["blas"] or "torch_error" in fp["blas"])
    html = (run / "report" / "index.html").read_text()
    assert fp["cpu_model"] in html and card["weights_sha256"] in html


def test_a_second_run_name_trains_nothing_scores_nothing_and_gives_the_same_bytes(smoke, tmp_path):
    """The stage cache (stages/framework/stage_cache.py): the smoke chain again under another
    run.name reuses every shared stage of the first; only the report (its page names the run) runs.
    It runs in an artifacts folder of its own holding the shared folder's cache (hard links: the
    same entries), so the chain tests that copy every run of the shared folder never see it."""
    run, _ = smoke
    art = tmp_path / "artifacts"
    shutil.copytree(run.parent / ".stage-cache", art / ".stage-cache", copy_function=os.link)
    again = art / "smoke_again"
    p = _viewfuse("evaluate", "--set", "run.name=smoke_again", artifacts=art)
    assert p.returncode == 0, p.stderr[-4000:]
    for stage in ("data", "classifier", "features", "models", "evaluate"):
        assert f"[{stage}] reused from run 'smoke'" in p.stdout, (stage, p.stdout[-3000:])
        assert f"[{stage}] running" not in p.stdout
        m = json.loads((again / stage / "manifest.json").read_text())
        assert m["reused"]["run"] == "smoke"
        for rel in m["outputs"]:
            assert (again / stage / rel).read_bytes() == (run / stage / rel).read_bytes(), (stage, rel)
    assert (again / "report" / "index.html").is_file()
