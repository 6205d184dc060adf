"""The main report, strict, from the results of several differently behaving classifiers: a trained
classifier moves every number downstream (another seed, another processor), so a page that builds
only with the numbers the project has seen is a page that breaks on a new machine. Each case is a
fake run in the evaluate contract (tests/support/report_fixtures.py: statistics computed from its
rows as the evaluate stage does) whose methods' evidence strength and noise differ as they do
between classifiers: With Uncertainty ahead, Model Based ahead, and a noisy, overconfident one
whose log10 MGR percentiles reach tens (the wide symlog axis of the forest plot)."""
from __future__ import annotations

import re

import pytest

import tests.support.report_fixtures as F

pytestmark = pytest.mark.slow   # three full renders

# (seed, drift per method, noise per method): evidence per step toward the truth, and its spread
CLASSIFIERS = {
    "seed0-ours-ahead": (0, {"with_uncertainty": 0.8, "model_based": 0.3, "simple_bayes": 0.2},
                         {"with_uncertainty": 0.4, "model_based": 1.2, "simple_bayes": 0.8}),
    "seed1-baseline-ahead": (1, {"with_uncertainty": 0.2, "model_based": 0.9, "simple_bayes": 0.6},
                             {"with_uncertainty": 1.0, "model_based": 0.3, "simple_bayes": 0.4}),
    # log-odds steps of tens of nats: MGR percentiles of 1e30 and more (kept below float underflow)
    "seed2-overconfident": (2, {"with_uncertainty": 3.0, "model_based": -4.0, "simple_bayes": 1.0},
                            {"with_uncertainty": 8.0, "model_based": 40.0, "simple_bayes": 5.0}),
}


@pytest.mark.parametrize("name", sorted(CLASSIFIERS))
def test_the_strict_report_builds_for_every_classifier(name, tmp_path, monkeypatch):
    from reports.main.page import build_main_report

    seed, drift, noise = CLASSIFIERS[name]
    monkeypatch.setattr(F, "DRIFT", drift)
    monkeypatch.setattr(F, "NOISE", noise)
    facts = F.write_fake_run(tmp_path / "run", K=4, R=4, seed=seed, n_boot=200)
    pop = facts["summary"]["population"]
    res = build_main_report(facts["run"], tmp_path / "out", run_name=name, dpi=80, progress=False, n_boot=200,
                            strict=True, config={"data": {"source": "synthetic"}, "report": {"dpi": 80}})
    html = res.index.read_text()
    assert 'class="scorecard' in html
    # the page prints this run's own verdict for the primary comparison, whichever way it went
    rec = next(r for r in pop["records"] if r["comparison"] == "with_uncertainty-model_based"
               and r["metric"] == "correct_final")
    assert rec["outcome"] in html
    if name == "seed2-overconfident":   # the case the forest plot's axis must survive
        mgr = [abs(r["value"]) for r in pop["records"] if r["metric"].startswith("log10_mgr")]
        assert max(mgr) > 30, mgr
    assert not re.search(r"Self-check failed", html)
