"""The report shows a fourth method from the results it is given: the Dirichlet row in the pooled
table, its paired comparison with With Uncertainty, and the note that it ignores poses."""
from __future__ import annotations

import copy
import json

from pipeline.evaluation.metrics import labels
from reports.main.page import build_main_report
from reports.shared.numbers import Estimate
from tests.support.report_fixtures import only_figures, write_fake_run
from tests.reports.test_report import parse

import pytest

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


def test_report_shows_the_dirichlet_when_the_results_hold_it(tmp_path, monkeypatch):
    only_figures(monkeypatch, "forest.png")   # the figure that draws a row per paired comparison
    facts = write_fake_run(tmp_path / "run", K=4, R=5, ablation=False)
    path = tmp_path / "run" / "evaluate" / "summary.json"
    summary = json.loads(path.read_text())
    pop = summary["population"]
    # Give the fake population a fourth method: numbers of its own, so the rows cannot be copies.
    pop["methods"] = pop["methods"] + ["dirichlet"]
    pop["pooled"]["dirichlet"] = {k: {"value": 0.5 + 0.01 * i, "ci_low": 0.4, "ci_high": 0.6 + 0.01 * i}
                                  for i, k in enumerate(pop["pooled"]["simple_bayes"])}
    d = copy.deepcopy(pop["paired"]["with_uncertainty-simple_bayes"])
    d["correct_final"].update(value=0.123, ci_low=0.05, ci_high=0.2, wins=0.4, losses=0.1)
    pop["paired"]["with_uncertainty-dirichlet"] = d
    pop["paired_per_target"]["with_uncertainty-dirichlet"] = pop["paired_per_target"]["with_uncertainty-simple_bayes"]
    pop["dirichlet"] = {"n_ss": 100, "truth_std_final": {"median": 0.031, "q25": 0.01, "q75": 0.05, "max": 0.2,
                                                         "n_cells": 6}}
    path.write_text(json.dumps(summary))
    dj = tmp_path / "run" / "models" / "dirichlet"
    dj.mkdir(parents=True)
    (dj / "index.json").write_text(json.dumps({
        "dim": 12, "floor": 1e-6, "fit": {"passes": "deterministic", "tol": 1e-10, "max_iter": 20000},
        "diagnostics": [{"class": "a", "n": 120, "precision": 35.5, "iterations": 14, "converged": True,
                         "log_likelihood": 4321.0},
                        {"class": "b", "n": 120, "precision": 3.5e4, "iterations": 20000, "converged": False,
                         "log_likelihood": 1.0}]}))
    res = build_main_report(facts["run"], tmp_path / "out", run_name="fake", dpi=40, progress=False, n_boot=100,
                            config={"data": {"source": "synthetic"}}, timings={})
    page = parse(res.index)
    header, *rows = page.table("pooled")["rows"]
    assert [r[0] for r in rows][-1] == labels.method_label("dirichlet") == "Dirichlet (Tchuiev & Indelman)"
    assert rows[-1][1] == Estimate.of(pop["pooled"]["dirichlet"]["correct_final"]).text()
    paired = [r for r in page.table("paired")["rows"][1:] if r[0] == "With Uncertainty − Dirichlet"]
    assert paired and paired[0][1] == "correct, final" and paired[0][2] == "better"
    assert paired[0][3] == "—"                 # no Holm fields in this summary: unadjusted only
    assert paired[0][4] == Estimate.of(d["correct_final"], signed=True).text()
    text = res.index.read_text()
    assert "ignores the poses" in text and "same for every localization realization" in text
    assert "median std of P(truth) at the final step of 0.0310" in text
    assert "forest.png" in res.figures
    fits = page.table("dirichlet-fits")
    assert fits["collapsed"] and fits["section"] == "diagnostics"
    assert fits["rows"][1:] == [["a", "120", "35.5", "14", "yes", "4320"], ["b", "120", "35000", "20000", "no", "1.00"]]
    assert "1 did not converge within 20000 steps" in text
