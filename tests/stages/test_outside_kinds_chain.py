"""A classifier, a planner, a metric and a fusion method from a package outside the repository
(tests/support/outside_kinds.py, the package tests/test_extending.py uses through the Python API),
found through their entry points by ``viewfuse evaluate`` started from the command line: the smoke
run's data stage (shared, copied) with ``classifier.arch`` naming the outside network (its weights a
file written here), so the classifier, features, models, evaluate and report stages run on its
scores, planning runs the outside planner beside the built-ins, and every table reports the outside
metric and method. Small: one track per target, three planning steps, two localization settings."""
from __future__ import annotations

import hashlib
import json

import numpy as np
import pandas as pd
import pytest

from tests.support.outside_kinds import ENTRY_POINTS, MODULE, PACKAGE
from tests.support.outside_package import run_with, write_package
from tests.support.shared_upstream import copy_upstream, run_evaluate, smoke_upstream

pytestmark = pytest.mark.slow  # five stages through the CLI on the smoke run's data

OUTPUTS = 6   # the outside network's outputs (weights given by a file: any number)

WEIGHTS = '''
import sys
import torch
from pipeline.scoring.classifiers import classifier
from pipeline.scoring.weight_files import save_state_dict_npz
torch.manual_seed(0)
save_state_dict_npz(classifier("outside_tiny").build(int(sys.argv[2]), 0.5), sys.argv[1])
'''

SETS = {"classifier.arch": "outside_tiny", "classifier.weights": "path",
        "evaluate.experiments": '["biased", "randomized"]', "evaluate.randomized.realizations": "2",
        "evaluate.randomized.n_loc_samples": "3", "evaluate.biased.n_loc_samples": "3",
        "plan.enabled": "true", "plan.budget": "3", "plan.starts": "1", "plan.eig_samples": "4"}


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("outside_kinds")
    site = write_package(tmp / "site", PACKAGE, MODULE, ENTRY_POINTS)
    npz = tmp / "outside_tiny.npz"
    # the weights file, built by the outside class in an interpreter that found it through its entry point
    r = run_with(site, f"import sys; sys.argv = ['', {str(npz)!r}, '{OUTPUTS}']\n" + WEIGHTS, tmp)
    assert r.returncode == 0, r.stderr[-3000:]
    art = copy_upstream(smoke_upstream(tmp_path_factory, "data"), tmp / "artifacts", ("data",))
    r = run_evaluate(art, ["-m", "stages.commands.cli"], site, {**SETS, "classifier.path": str(npz)})
    assert r.returncode == 0, r.stderr[-3000:]
    return {"run": art / "smoke", "stdout": r.stdout}


def _json(path):
    return json.loads(path.read_text())


def test_the_outside_classifier_scores_the_features_and_its_source_keys_them(chain):
    from stages.framework.runner import digest

    run = chain["run"]
    assert "[data] up to date" in chain["stdout"]                # the shared data stage was reused
    card = _json(run / "classifier" / "card.json")
    assert (card["arch"], card["architecture"], card["num_classes"]) == ("outside_tiny", "outside.tiny", OUTPUTS)
    cls = _json(run / "classifier" / "manifest.json")
    # the classifier stage's key holds the outside module's source (as the registry hashes it)
    assert cls["parts"]["classifiers"] == "outside_tiny=" + hashlib.sha256(MODULE.encode()).hexdigest()[:16]
    feats = _json(run / "features" / "manifest.json")
    # ... and the features key holds that stage's digest and the outside network's card hash
    assert feats["parts"]["upstream"]["classifier"] == digest(cls)
    assert feats["parts"]["inputs"] == "classifier=" + card["hash"]
    assert feats["extra"]["classifier_hash"] == card["hash"] and feats["extra"]["score_dim"] == OUTPUTS
    assert feats["extra"]["avd_crops"] > 0 and feats["extra"]["bigbird_crops"] > 0


def test_planning_runs_the_outside_planner_beside_the_builtins(chain):
    run = chain["run"]
    plan = _json(run / "evaluate" / "summary.json")["planning"]
    assert plan["planners"][-1] == "outside_first" and "info_gain" in plan["planners"]
    assert "outside_first" in plan["curves"] and "outside_first" in plan["pooled"]
    eps = pd.read_parquet(run / "evaluate" / "planning.parquet")
    ours, theirs = eps[eps.planner == "outside_first"], eps[eps.planner == "info_gain"]
    key = ["target", "start", "setting"]
    # the same episodes (every target, start and setting) as a built-in planner, each its full budget
    assert len(ours) > 0 and ours[key].drop_duplicates().shape[0] == theirs[key].drop_duplicates().shape[0]
    assert sorted(ours.step.unique()) == [1, 2, 3] and ours.measured.any()
    first = ours[ours.step == 1].set_index(key).node.sort_index()
    assert first.equals(theirs[theirs.step == 1].set_index(key).node.sort_index())   # same start views
    ev = _json(run / "evaluate" / "manifest.json")["parts"]
    assert ev["planners"].startswith("outside_first=") and ev["metrics"].startswith("p_truth_squared_final=")
    assert ev["methods"].startswith("outside_vote=")


def test_the_outside_metric_is_reported_for_every_cell_and_method(chain):
    run = chain["run"]
    pop = _json(run / "evaluate" / "summary.json")["population"]
    assert "p_truth_squared_final" in pop["pooled"]["with_uncertainty"]
    rows = pd.read_parquet(run / "evaluate" / "results.parquet")
    assert len(pop["cells"]) > 0
    for cell in pop["cells"]:
        for method, values in cell["values"].items():
            r = rows[(rows.experiment == cell["experiment"]) & (rows.target == cell["target"])
                     & (rows.track == cell["track"]) & (rows.method == method)]
            final = r[r.step == r.step.max()].p_truth.to_numpy()
            assert len(final) > 0, (cell, method)
            # the metric's reduction: P(truth) squared at the final step, averaged over realizations
            assert values["p_truth_squared_final"] == pytest.approx(np.mean(final ** 2), abs=1e-9), (cell, method)
    html = (run / "report" / "index.html").read_text()
    assert "P(truth)^2, final" in html


def test_the_outside_method_has_results_and_a_pooled_row(chain):
    run = chain["run"]
    pop = _json(run / "evaluate" / "summary.json")["population"]
    assert pop["methods"][-1] == "outside_vote"
    pooled = pop["pooled"]["outside_vote"]
    assert 0.0 <= pooled["prob_truth_final"]["value"] <= 1.0
    assert pooled["p_truth_squared_final"]["n"]["targets"] == len(pop["targets"]) > 0
    rows = pd.read_parquet(run / "evaluate" / "results.parquet")
    ours = rows[rows.method == "outside_vote"]
    assert len(ours) == len(rows[rows.method == "simple_bayes"]) > 0
    assert np.allclose([np.sum(p) for p in ours.posterior], 1.0)
    assert "Outside vote (test package)" in (run / "report" / "index.html").read_text()
