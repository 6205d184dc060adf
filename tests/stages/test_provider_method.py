"""A method with a model of its own, from a package outside the repository (docs/extending.md, "A
method with its own model"): its provider and two methods enter through one entry point of
``viewfuse.methods``; the models stage fits and saves the provider's models beside the GP bank
(and records their digest), evaluate loads them and hands them to both methods
(``TrackInput.models``), a pose-using method gets its own random stream (``TrackInput.rng``), and
the pose-free method's extras reach summary.json under its key (``population_block``)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.support.outside_package import write_package
from tests.support.shared_upstream import copy_upstream, run_evaluate, smoke_upstream

pytestmark = pytest.mark.slow  # reruns the smoke chain's models and evaluate stages

MODULE = '''
import hashlib
import json

import numpy as np
import viewfuse as vf


@vf.register_provider
class MeanVectors(vf.ModelProvider):
    """Per class, the mean of its training views' probability vectors."""
    key = "mean_vectors"
    label = "mean probability vectors"

    def fit(self, views, cfg):
        means = {c: views.scores[views.objects == c].mean(axis=0).tolist() for c in views.classes}
        return means, {"views": int(len(views.objects))}

    def save(self, models, folder, extra):
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "means.json").write_text(json.dumps({"means": models, **extra}, sort_keys=True))

    def load(self, folder, cfg):
        return json.loads((folder / "means.json").read_text())["means"]

    def digest(self, models):
        return hashlib.sha256(json.dumps(models, sort_keys=True).encode()).hexdigest()

    def record(self, models, extra):
        return {"classes": len(models)}

    def summary(self, models, extra, cfg):
        return f"{len(models)} mean vectors"

    def for_cell(self, models, target, classes, dim):
        m = np.array([models[c] for c in classes])
        if m.shape[1] != dim:
            raise ValueError(f"{dim} scores per crop, the means {m.shape[1]}")
        return m


def _loglik(t):
    d = ((t.probs.mean(axis=1)[:, None, :] - t.models["mean_vectors"][None]) ** 2).sum(-1)   # (K, C)
    return np.cumsum(-20.0 * d, axis=0)


@vf.register
class NearestMean(vf.FusionMethod):
    key = "nearest_mean"
    label = "Nearest mean (outside)"
    needs = frozenset({"mean_vectors", "probs"})
    uses_poses = False

    def fuse_with_extras(self, t):
        log = _loglik(t)
        log = log - np.logaddexp.reduce(log, axis=1, keepdims=True)
        return log, {"top": log.argmax(axis=1)}

    def fuse(self, t):
        return self.fuse_with_extras(t)[0]

    def population_block(self, cfg, pairs):
        return {"cells": len(pairs), "final_top_is_truth": float(np.mean([x["top"][-1] == c.truth for c, x in pairs])),
                "first_posterior": pairs[0][1]["posterior0"].tolist()}


@vf.register
class NoisyMean(vf.FusionMethod):
    """Pose-using: the same distances with noise from the method's own stream."""
    key = "noisy_mean"
    needs = frozenset({"mean_vectors", "probs"})

    def fuse(self, t):
        R = len(t.estimates)
        log = _loglik(t)[None] + 0.01 * t.rng.standard_normal((R,) + _loglik(t).shape)
        return log - np.logaddexp.reduce(log, axis=2, keepdims=True)
'''


def test_an_outside_method_with_its_own_model_runs_through_models_and_evaluate(tmp_path_factory, tmp_path):
    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path / "artifacts")
    site = write_package(tmp_path / "site", "vf_mean_vectors", MODULE,
                         {"viewfuse.methods": {"mean_vectors": "vf_mean_vectors"}})
    r = run_evaluate(art, ["-m", "stages.commands.cli"], site)
    assert r.returncode == 0, r.stderr[-3000:]
    run = art / "smoke"
    # the models stage reran (the provider's source is in its key), fitted and saved the provider's models
    saved = json.loads((run / "models" / "mean_vectors" / "means.json").read_text())
    bank = json.loads((run / "models" / "index.json").read_text())
    assert sorted(saved["means"]) == sorted(bank["classes"]) and saved["views"] > 0
    for c, mean in saved["means"].items():
        assert np.isclose(sum(mean), 1.0, atol=1e-3)           # a mean of probability vectors
    assert (run / "models" / "dirichlet" / "index.json").is_file()   # the built-in provider still fitted
    pop = json.loads((run / "evaluate" / "summary.json").read_text())["population"]
    for key in ("nearest_mean", "noisy_mean"):
        assert key in pop["methods"] and key in pop["pooled"], key
    block = pop["nearest_mean"]
    assert block["cells"] == len(pop["tracks"]) > 0                # one default cell per track
    assert 0.0 <= block["final_top_is_truth"] <= 1.0
    first = np.array(block["first_posterior"])
    assert np.allclose(first.sum(axis=1), 1.0)
    # the two methods read the same models: the pose-using one's noise is small
    a = pop["pooled"]["nearest_mean"]["prob_truth_final"]["value"]
    b = pop["pooled"]["noisy_mean"]["prob_truth_final"]["value"]
    assert abs(a - b) < 0.05
    assert "dirichlet" in pop and pop["dirichlet"]["truth_std_final"]["n_cells"] > 0
