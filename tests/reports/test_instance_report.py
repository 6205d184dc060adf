"""The report's instance sections: the instance fits of a tiny bank fitted here (one class with three
training instances that differ by a known offset, one with a single instance and so no term), shown
through their provider's section (``reports.main.provided``), and the instance term's attribution and
per-category tables from a generated population."""
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.evaluation.metrics.labels import comparison_key, comparison_label
from pipeline.method.gp_files import save_bank
from pipeline.method.gp_instance_fit import NO_TERM, fit_instance_models
from pipeline.method.names import MB_INSTANCE, MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE
from reports.main.context import ReportContext
from pipeline.method.methods.instance_term import INSTANCE_TERM
from reports.main.instances import category_section, instance_attribution_section
from reports.main.provided import sections as provided_sections
from reports.shared.artifacts import RunArtifacts, load_run, read_json
from reports.shared.html import HtmlReport
from reports.shared.numbers import Estimate
from tests.pipeline.evaluation.grid.test_instance_attribution import _blocks, _population
from tests.reports.test_report import parse


def _ring(n):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([np.cos(th), np.sin(th)], axis=1)


def _bank(folder: Path) -> dict:
    """Class 'mug__f0': 3 instances x 12 views; component 0 = class curve + an instance offset of sd
    1 (b = 1 in truth, constant along the ring), component 1 = class curve alone. Class 'cup__f1': one
    instance."""
    rng = np.random.default_rng(3)
    X = _ring(12)
    offsets = [-1.2, 0.1, 1.1]
    Xm = np.concatenate([X] * 3)
    base = 0.3 * np.sin(np.arctan2(Xm[:, 1], Xm[:, 0]))
    ym = np.stack([base + np.repeat(offsets, 12) + rng.normal(0, 0.02, 36), base + rng.normal(0, 0.02, 36)])
    yc = np.stack([0.2 * X[:, 0] + rng.normal(0, 0.02, 12), 0.1 * X[:, 1] + rng.normal(0, 0.02, 12)])
    models, diags = fit_instance_models([Xm, X], [ym, yc], [np.repeat(["a", "b", "c"], 12), np.repeat(["z"], 12)],
                                        ["mug__f0", "cup__f1"], [0, 1], restarts=1, progress=False,
                                        component_names=["offset", "flat"])
    save_bank(models, folder, extra={"diagnostics": diags})
    return read_json(folder / "index.json")


def _ctx(tmp_path, pop=None) -> ReportContext:
    run = RunArtifacts(tmp_path, SimpleNamespace(population=pop))
    return ReportContext(HtmlReport("t"), run)


def _render(ctx, tmp_path):
    ctx.page.write(tmp_path / "index.html")
    return parse(tmp_path / "index.html")


def test_the_fits_section_shows_the_instance_term_per_category_component_and_fit(tmp_path):
    index = _bank(tmp_path / "models" / INSTANCE_TERM)
    (tmp_path / "evaluate").mkdir()
    (tmp_path / "evaluate" / "summary.json").write_text(json.dumps({"population": {}}))
    run = load_run(tmp_path)           # the run's reader finds the instance bank's index
    assert run.provided[INSTANCE_TERM] == index and run.index is None
    ctx = ReportContext(HtmlReport("t"), run)
    provided_sections(ctx)
    page = _render(ctx, tmp_path)
    assert ctx.sections == ["instance-fits"]
    header, *rows = page.table("instance-fits-category")["rows"]
    assert [r[0] for r in rows] == ["cup", "mug"]
    assert rows[0][1:4] == ["2", "0", "0"] and rows[0][4] == "—"      # one instance: no term fitted
    assert rows[1][1:3] == ["2", "2"]
    fits = page.table("instance-fits")
    assert fits["collapsed"] and len(fits["rows"]) == 5
    by = {(r[0], r[1]): r for r in fits["rows"][1:]}
    # the offset component's instance amplitude is near the offsets' variance and far above the class's
    d = next(x for x in index["diagnostics"] if x["class"] == "mug__f0" and x["component"] == 0)
    assert 0.2 < d["instance_amplitude"] < 5 and d["instance_ratio"] > 3
    assert by[("mug__f0", "offset")][4] == Estimate(d["instance_amplitude"]).text()
    assert by[("cup__f1", "flat")][-1] == NO_TERM
    text = (tmp_path / "index.html").read_text()
    assert f"No instance term: cup__f1 ({NO_TERM})." in text
    comp = {r[0]: r for r in page.table("instance-fits-component")["rows"][1:]}
    assert set(comp) == {"offset", "flat"} and comp["offset"][2] == "1"


def test_no_instance_bank_no_section(tmp_path):
    ctx = _ctx(tmp_path, pop={})
    provided_sections(ctx)
    instance_attribution_section(ctx)
    category_section(ctx)
    assert ctx.sections == []


def test_attribution_and_category_tables_read_the_engine_blocks(tmp_path):
    # 8 targets a category: fewer units get no interval and no verdict (the design interval's floor)
    out = _blocks(*_population(np.random.default_rng(5), per_cat=8))
    pop = {"ablations": out["ablations"], "by_category": out["by_category"]}
    ctx = _ctx(tmp_path, pop=pop)
    instance_attribution_section(ctx)
    category_section(ctx)
    page = _render(ctx, tmp_path)
    assert ctx.sections == ["instance-attribution", "by-category"]
    rows = {r[0]: r for r in page.table("instance-attribution")["rows"][1:]}
    key = comparison_key(MB_INSTANCE, MODEL_BASED)
    want = out["ablations"]["instance_term"]["paired"][key]["correct_final"]
    assert rows[comparison_label(key)][1] == "the instance term alone (no pose or dropout sampling)"
    assert rows[comparison_label(key)][2] == Estimate.of(want, signed=True).text()
    correct = {r[0]: r for r in page.table("correct_final")["rows"][1:]}
    assert sorted(correct) == ["cat0", "cat1", "cat2", "cat3"] and correct["cat0"][1] == "8"
    wu = comparison_label(comparison_key(WU_INSTANCE, WITH_UNCERTAINTY))
    # the term gains in cat0 only, in every cell: the finding names cat0 and no other category
    assert (f"{wu}, confident errors: fewer in cat0; more in no category (95 % CI excludes 0, of 4 categories "
            "with a CI; unadjusted).") in page.verdict
    assert any(s.startswith(f"{wu}, correct answers: more in cat0;") for s in page.verdict)
    assert len(page.table("instance-paired")["rows"][0]) == 1 + 3 * 2


def test_categories_without_a_ci_are_named_apart_never_counted_as_no_category(tmp_path):
    # 7 targets a category: every category's interval withheld (the design interval's floor)
    out = _blocks(*_population(np.random.default_rng(5), per_cat=7))
    ctx = _ctx(tmp_path, pop={"ablations": out["ablations"], "by_category": out["by_category"]})
    category_section(ctx)
    page = _render(ctx, tmp_path)
    wu = comparison_label(comparison_key(WU_INSTANCE, WITH_UNCERTAINTY))
    (line,) = [s for s in page.verdict if s.startswith(f"{wu}, confident errors:")]
    assert "fewer in no category with a CI" in line and "of 0 categories with a CI" in line, line
    assert "no CI, no verdict in cat0 (7 targets), cat1 (7 targets)" in line, line
    # the goal per category: neither met nor missed where its differences carry no CI
    goal = page.table("instance-goal-category")["rows"][1:]
    assert goal and all(r[1] == "not judged" and "no CI, no verdict" in r[2] for r in goal), goal


def test_the_goal_is_read_off_the_intervals_pooled_and_per_category(tmp_path):
    out = _blocks(*_population(np.random.default_rng(6), per_cat=8))   # 8 a category: intervals given
    ctx = _ctx(tmp_path, pop={"ablations": out["ablations"], "by_category": out["by_category"]})
    instance_attribution_section(ctx)
    category_section(ctx)
    page = _render(ctx, tmp_path)
    goal = {r[0]: r for r in page.table("instance-goal")["rows"][1:]}
    assert sorted(goal) == ["Model Based", "Simple Bayes"]
    text = (tmp_path / "index.html").read_text()
    # pooled: one category of four gains in every cell, the others tie: every CI lies below 0
    assert "a correct ratio not worse than Simple Bayes&#x27;s): met." in text
    per = {r[0]: r[1:] for r in page.table("instance-goal-category")["rows"][1:]}
    assert per["cat0"] == ["met", "—"]
    assert per["cat2"][0] == "missed" and "confident errors not fewer than Simple Bayes" in per["cat2"][1]


def test_goal_misses_name_each_failing_baseline():
    from reports.main.instances import goal_misses, goal_sentence

    def est(v, lo, hi):
        return {"value": v, "ci_low": lo, "ci_high": hi}

    goal = ((WU_INSTANCE, MODEL_BASED), (WU_INSTANCE, "simple_bayes"))
    paired = {comparison_key(WU_INSTANCE, MODEL_BASED): {"confident_error_final": est(-0.05, -0.08, -0.01)},
              comparison_key(WU_INSTANCE, "simple_bayes"): {"confident_error_final": est(0.09, 0.01, 0.17),
                                                            "correct_final": est(-0.16, -0.3, -0.02)}}
    misses = goal_misses(paired, goal)
    assert len(misses) == 2 and misses[0].startswith("confident errors not fewer than Simple Bayes")
    assert misses[1].startswith("correct ratio below Simple Bayes")
    paired[comparison_key(WU_INSTANCE, "simple_bayes")] = {"confident_error_final": est(-0.02, -0.04, -0.001),
                                                           "correct_final": est(-0.05, -0.2, 0.1)}
    assert goal_misses(paired, goal) == [] and goal_sentence(paired, goal).endswith("met.")


@pytest.mark.slow   # builds the whole page of a fake run (tests/support/report_fixtures.py)
def test_the_whole_page_carries_the_instance_sections(tmp_path, monkeypatch):
    from reports.main.page import build_main_report
    from tests.support.report_fixtures import only_figures, write_fake_run

    only_figures(monkeypatch)
    facts = write_fake_run(tmp_path / "run", K=4, R=5, ablation=False)
    _bank(tmp_path / "run" / "models" / INSTANCE_TERM)
    path = tmp_path / "run" / "evaluate" / "summary.json"
    summary = json.loads(path.read_text())
    out = _blocks(*_population(np.random.default_rng(7)))
    summary["population"]["ablations"] = {**(summary["population"].get("ablations") or {}),
                                          "instance_term": out["ablations"]["instance_term"]}
    summary["population"]["by_category"] = out["by_category"]
    path.write_text(json.dumps(summary))
    res = build_main_report(facts["run"], tmp_path / "out", run_name="fake", dpi=40, progress=False, n_boot=100,
                            config={"data": {"source": "synthetic"}}, timings={})
    page = parse(res.index)
    for anchor in ("instance-fits", "instance-attribution", "by-category"):
        assert anchor in page.sections
    assert page.sections.index("diagnostics") < page.sections.index("instance-fits")
    assert page.table("instance-fits-category")["section"] == "instance-fits"
    assert page.table("instance-goal")["section"] == "instance-attribution"
