"""A fifth fusion method registered from tests/ alone (tests/support/toy_method.py, no product
code edited) runs through a small chain: it is in summary.json (pooled values, a paired comparison
and its verdict records, the difficulty), in results.parquet, on the report's tables and method
notes, and on the compare page; the simulation fuses it too."""
import html
import json

import pyarrow.parquet as pq
import pytest

from tests.support.shared_upstream import copy_upstream, smoke_config, smoke_upstream
from tests.support.toy_method import KEY, ToyTempered

pytestmark = pytest.mark.slow  # runs real stages

SMALL = {"evaluate": {"ablations": [], "attribution": False, "tracks_per_target": 1, "bootstrap": 100,
                      "randomized": {"sigmas_m": [0.3]}},
         "plan": {"enabled": False},
         "simulate": {"realizations": 12, "sweep": "off"}}


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    from pipeline.method import registry
    from stages.framework.runner import ensure

    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path_factory.mktemp("toy") / "artifacts")
    cfg = smoke_config(art, SMALL)
    registry.register(ToyTempered)
    try:
        keys: dict = {}
        for stage in ("evaluate", "report", "simulate"):
            ensure(cfg, stage, device="cpu", _keys=keys)
        yield cfg
    finally:
        registry.unregister(KEY)


def test_the_toy_method_is_in_the_summary_and_the_results(toy_run):
    ev = toy_run.stage_dir("evaluate")
    pop = json.loads((ev / "summary.json").read_text())["population"]
    assert KEY in pop["methods"] and KEY in pop["pooled"]
    assert f"with_uncertainty-{KEY}" in pop["paired"]
    assert any(r.get("comparison") == f"with_uncertainty-{KEY}" for r in pop["records"])
    assert KEY in pop["difficulty"]["summary"]
    methods = set(pq.read_table(ev / "results.parquet", columns=["method"]).column("method").to_pylist())
    assert KEY in methods and "with_uncertainty" in methods


def test_the_report_and_the_compare_page_show_it(toy_run):
    from reports.compare.page import write_page
    from reports.compare.runs import compare

    report = (toy_run.stage_dir("report") / "index.html").read_text()
    note = ToyTempered.note
    assert ToyTempered.label in report and ToyTempered.short in report
    assert any(n in report for n in (note, html.escape(note), html.escape(note, quote=False))), "method note"
    c = compare([toy_run.stage_dir("evaluate").parent])
    assert any(m == KEY for m, _ in c.pooled)
    page = write_page(c, toy_run.stage_dir("evaluate").parent / "compare_toy")
    shown = (page if page.suffix == ".html" else page / "index.html").read_text()
    assert ToyTempered.short in shown


def test_the_simulation_fuses_it(toy_run):
    sim = toy_run.stage_dir("simulate")
    methods = set(pq.read_table(sim / "results.parquet", columns=["method"]).column("method").to_pylist())
    assert KEY in methods and "dirichlet" not in methods
    assert ToyTempered.short in (sim / "index.html").read_text()
