"""The report's view-planning section and ``viewfuse compare``'s planning rows show the numbers
of the summary's planning block (one statistic per number), from a hand-built planning run."""
from __future__ import annotations

import json

import pytest

from pipeline.planning.evaluation import episode_table, example_path
from pipeline.planning.population import run_task
from pipeline.planning.summary import planning_block
from tests.pipeline.planning.test_population import banks, tasks
from tests.reports.test_report import estimate, parse
from tests.support.report_fixtures import only_figures, write_fake_run


@pytest.fixture(scope="module")
def block():
    ts = tasks(2, 2)
    results = [run_task(banks(), t) for t in ts]
    b = planning_block(episode_table(ts, results)[0], ts[0].planners, 5, 0.9, 100, 0)
    b["example"] = example_path(ts, results)
    return b


def with_planning(run, block):
    p = run / "evaluate" / "summary.json"
    s = json.loads(p.read_text())
    s["planning"] = block
    s.setdefault("timings_s", {}).update(planning_decision_ms_median=3.0, planning_decision_ms_p90=5.0,
                                         planning_decisions=10.0)
    p.write_text(json.dumps(s))


PLANNING_FIGURES = ("planning_curves.png", "planning_map.png")


def test_the_section_shows_the_block(tmp_path, block, monkeypatch):
    from reports.main.page import build_main_report

    only_figures(monkeypatch, *PLANNING_FIGURES)   # the other figures do not depend on planning

    facts = write_fake_run(tmp_path / "run", K=3, R=3, n_boot=50)
    with_planning(facts["run"], block)
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False, n_boot=50)
    page = parse(res.index)
    assert "planning" in page.sections
    assert set(PLANNING_FIGURES) <= set(res.figures)
    rows = page.table("planning")["rows"][1:]
    from reports.main.planning import name
    assert [r[0] for r in rows] == [name(p) for p in block["planners"]]
    for p, r in zip(block["planners"], rows):
        want = block["pooled"][p]["steps_to_decision"]
        # 2 targets: the engine's rule withholds the interval, so the cell is the value alone
        assert want["withheld"] and "[" not in r[1] and float(r[1]) == pytest.approx(want["value"], rel=5e-3)
    html = res.index.read_text()
    from reports.main.planning import verdict_sentences
    sentences = verdict_sentences(block)
    assert len(sentences) >= 3 and all(s.split(" (")[0] in html for s in sentences)
    # each sentence's label is its entry's outcome under the one rule
    from pipeline.evaluation.statistics.records import consistent, outcome
    for entries in block["paired"].values():
        for e in entries.values():
            assert e["outcome"] == ("withheld" if e.get("withheld") else
                                    outcome(e["ci_low"], e["ci_high"], e["better"] == "higher"))
    # the entries are verdict records, worded by the one renderer like every other verdict
    from reports.main.planning import verdict_records
    from reports.shared.records import PHRASE
    recs = verdict_records(block)
    assert len(recs) == len(sentences) and all(consistent(r) for r in recs)
    for r, s in zip(recs, sentences):
        assert r["outcome"] == block["paired"][r["comparison"]][r["metric"]]["outcome"]
        assert f" {PHRASE[r['outcome']]} " in s and "mean over targets of the differences" in s
        assert r["outcome"] == "withheld" and "no CI, no verdict" in s
        assert f"over {r['n']['targets']} targets × {r['n']['starts']} starts" in s


def test_a_run_without_planning_has_no_section(tmp_path, monkeypatch):
    from reports.main.page import build_main_report

    only_figures(monkeypatch, *PLANNING_FIGURES)   # drawn if the plan wrongly held them

    facts = write_fake_run(tmp_path / "run", K=3, R=3, n_boot=50)
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False, n_boot=50)
    assert "planning" not in parse(res.index).sections
    assert not any(f.startswith("planning") for f in res.figures)


def test_compare_shows_the_planning_rows(tmp_path, block):
    from reports.compare.page import render_text
    from reports.compare.runs import compare

    facts = write_fake_run(tmp_path / "run", K=3, R=3, n_boot=50)
    with_planning(facts["run"], block)
    c = compare([facts["run"]])
    got = {(p, m): v[0] for p, m, v in c.planning}
    assert got[("info_gain", "steps_to_decision")] == block["pooled"]["info_gain"]["steps_to_decision"]
    keys = {(k, m) for k, m, _ in c.planning_paired}
    assert ("info_gain-random", "correct_at_3") in keys
    assert "View planning" in render_text(c)


def test_a_planner_from_outside_is_named_and_coloured_by_its_own_declaration():
    """The report's planning table and figures name and colour a planner by its registry entry, so
    a planner from outside shows its own label and colour (not a built-in's, not a default)."""
    import viewfuse as vf
    from pipeline.planning.planners import PLANNERS
    from reports.main.planning import colour, name

    class OutsidePick(vf.Planner):
        key = "outside_pick"
        label = "Outside pick (a test's planner)"
        color = "#123456"
        note = "the first candidate in name order"

        def choose(self, belief, candidates, rng):
            return sorted(candidates)[0]

    vf.register(OutsidePick)
    try:
        assert name("outside_pick") == "Outside pick (a test's planner)" and colour("outside_pick") == "#123456"
        assert name("random") != name("outside_pick") and colour("random") != "#123456"
    finally:
        PLANNERS.remove("outside_pick")
    assert name("outside_pick") == "outside pick"   # gone from the registry: its key with spaces
