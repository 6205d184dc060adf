"""docs/extending.md, checked: a package outside the repository adds a fusion method, a classifier,
a planner and a metric through its entry points (a dist-info written here, on a subprocess's
PYTHONPATH); each is listed after the built-ins, is used through the public API, and its source
enters the cache key of the stages it changes. Without the package those keys gain nothing."""
from __future__ import annotations

import json

import pytest

from tests.support.outside_kinds import ENTRY_POINTS, MODULE, PACKAGE
from tests.support.outside_package import run_with, write_package

PROBE = '''
import json
import numpy as np
import viewfuse as vf
out = {"methods": vf.methods()}
# the method, used: a track of own scores fused through the public API
own = np.random.default_rng(0).dirichlet(np.ones(3), size=(4, 2))
lp = vf.fuse("outside_vote", cameras=np.zeros((4, 2)), dropout=np.zeros((4, 2, 1)), own=own)
want = np.cumsum(np.log(own.mean(1)), 0)
out["fused_ok"] = bool(np.allclose(np.exp(lp), np.exp(want) / np.exp(want).sum(1, keepdims=True), atol=1e-12))
# the classifier, used: built and MC-dropout scored at its declared site
import torch
from pipeline.scoring.classifiers import classifier, names
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
out["classifiers"] = names()
torch.manual_seed(0)
sc = MCDropoutScorer(classifier("outside_tiny").build(3, 0.5), onednn=False)
det, mc = sc.score(torch.rand(2, 3, 32, 32), [crop_seed(0, "a"), crop_seed(0, "b")], 5)
out["scored"] = [list(det.shape), list(mc.shape), float((mc - det[:, None]).abs().max())]
# the planner, used: one episode on the tests' ring world
from pipeline.planning.planners import PLANNERS, make_planner
from pipeline.planning.belief import Belief
from pipeline.planning.eig import standard_draws
from pipeline.planning.episode import run_episode
from tests.pipeline.planning.ring import models, ring_world
out["planners"] = list(PLANNERS)
b = Belief(models(), ring_world(0), bias=(0.0, 0.0), est_sigma=0.0, sigma=0.1, n_x=8, key=(0,))
ep = run_episode(b, make_planner("outside_first", standard_draws(8, 1, 0)), "v0", budget=3, confidence=None,
                 horizon=2, rng=np.random.default_rng(0))
out["episode"] = list(ep.nodes)
# the metric, used: in every track's metrics and a population's pooled value
out["metrics"] = list(vf.track_metrics(lp, 0))
rows = [{"target": t, "track": k, "method": "outside_vote", **vf.track_metrics(lp, i)}
        for i, t in enumerate("abc") for k in range(2)]
block = vf.evaluate_population(__import__("pandas").DataFrame(rows), metrics=["p_truth_squared_final"], n_boot=50)
out["pooled"] = block["pooled"]["outside_vote"]["p_truth_squared_final"]["value"]
out["expected"] = float(np.mean([np.exp(lp[-1, i]) ** 2 for i in range(3)]))
# the cache keys
from pipeline.method.registry import outside_fingerprint
from stages.framework.outside import outside_parts
from types import SimpleNamespace
cfg = SimpleNamespace(classifier=SimpleNamespace(arch="outside_tiny"))
out["keys"] = {s: outside_parts(cfg, s) for s in ("classifier", "features", "evaluate", "simulate", "report")}
out["alexnet_key"] = outside_parts(SimpleNamespace(classifier=SimpleNamespace(arch="alexnet")), "classifier")
out["method_key"] = outside_fingerprint()
print("PROBE " + json.dumps(out))
'''


def _probe(site, tmp_path) -> dict:
    r = run_with(site, PROBE, tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(next(line for line in r.stdout.splitlines() if line.startswith("PROBE "))[6:])


@pytest.fixture(scope="module")
def outside(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("outside")
    return _probe(write_package(tmp / "site", PACKAGE, MODULE, ENTRY_POINTS), tmp)


def test_a_method_from_an_entry_point_lists_after_the_builtins_and_fuses(outside):
    assert outside["methods"][:4] == ["with_uncertainty", "model_based", "simple_bayes", "dirichlet"]
    assert outside["methods"][-1] == "outside_vote" and outside["fused_ok"]
    assert outside["method_key"].startswith("outside_vote=")


def test_a_classifier_from_an_entry_point_lists_after_the_builtins_and_scores(outside):
    assert outside["classifiers"][:2] == ["alexnet", "efficientnet_lite0"]
    assert outside["classifiers"][-1] == "outside_tiny"
    det, mc, spread = outside["scored"]
    assert det == [2, 3] and mc == [2, 5, 3] and spread > 1e-4   # the head's Dropout samples
    assert set(outside["keys"]["classifier"]) == {"classifiers"}
    assert outside["keys"]["classifier"]["classifiers"].startswith("outside_tiny=")
    assert outside["alexnet_key"] == {}   # a run with another arch: its key does not move


def test_a_planner_from_an_entry_point_lists_after_the_builtins_and_plans(outside):
    assert outside["planners"] == ["info_gain", "known_pose", "random", "fixed", "orbit", "hindsight", "outside_first"]
    assert outside["episode"][0] == "v0" and len(outside["episode"]) > 1
    assert "planners" in outside["keys"]["evaluate"] and "planners" not in outside["keys"]["simulate"]


def test_a_metric_from_an_entry_point_lists_after_the_builtins_and_is_reported(outside):
    assert outside["metrics"][0] == "correct_final" and outside["metrics"][-1] == "p_truth_squared_final"
    assert outside["pooled"] == pytest.approx(outside["expected"], abs=1e-12)
    for stage in ("evaluate", "simulate"):
        assert outside["keys"][stage]["metrics"].startswith("p_truth_squared_final=")
    assert outside["keys"]["report"] == {} and outside["keys"]["features"] == {}


def test_an_entry_point_that_does_not_load_is_named(tmp_path):
    """Contained (docs/extending.md): the built-ins work, a warning names it, and the stages that
    would use the kind refuse with the same words."""
    site = write_package(tmp_path / "site", "vf_broken", "raise ImportError('missing dependency xyz')\n",
                         {"viewfuse.metrics": {"broken": "vf_broken:M"}})
    code = ("import numpy as np; import viewfuse as vf; vf.track_metrics(np.log(np.full((2, 2), 0.5)), 0); "
            "print('used'); from types import SimpleNamespace as N; "
            "from stages.framework.outside import check_loaded; check_loaded(N(), 'evaluate', True)")
    r = run_with(site, code, tmp_path)
    assert r.returncode != 0 and r.stdout.strip() == "used"
    why = "metric entry point 'broken' = 'vf_broken:M' of group 'viewfuse.metrics' does not load: ImportError"
    assert r.stderr.count(why) == 2, r.stderr[-3000:]      # the warning, then the stage's refusal
    assert "missing dependency xyz" in r.stderr


def test_without_outside_entries_the_stage_keys_gain_nothing(tmp_path):
    code = ("from types import SimpleNamespace as N; from stages.framework.outside import outside_parts; "
            "from pipeline.method.registry import outside_fingerprint; cfg = N(classifier=N(arch='alexnet')); "
            "print(repr([outside_parts(cfg, s) for s in ('classifier', 'evaluate', 'simulate')]), "
            "repr(outside_fingerprint()))")
    r = run_with(None, code, tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == ["[{},", "{},", "{}]", "''"]
