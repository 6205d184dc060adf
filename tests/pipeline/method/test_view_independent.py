"""The view-independent Gaussian baseline (pipeline/method/methods/view_independent.py): the literal
oracle to 1e-9 on a small generated track, its place among the registry's comparisons, and the
ablation it stands for (it cannot tell classes apart that differ only in how they vary with the
viewpoint, which the GP methods can)."""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.grid import experiments as E
from pipeline.method import registry
from pipeline.method.gp import GPClassModels
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models
from tests.support.literal_paper import literal_view_independent

KEY = "view_independent"


def random_models(C=3, F=2, seed=0) -> GPClassModels:
    """Classes with their own training inputs and view counts, different means and spreads."""
    rng = np.random.default_rng(seed)
    X, Y = [], []
    for c in range(C):
        n = 5 + 3 * c
        th = rng.uniform(-np.pi, np.pi, n)
        X.append(np.stack([np.cos(th), np.sin(th)], 1))
        Y.append(rng.normal(0.3 + 0.2 * c, 0.05 + 0.05 * c, (F, n)))
    ones = np.ones((C, F))
    return GPClassModels([f"c{c}" for c in range(C)], list(range(F)), X, Y, 0.5 * ones, 0.08 * ones,
                         0.7 * ones, 1e-3 * ones)


def test_fusion_matches_the_literal_oracle():
    models = random_models()
    rng = np.random.default_rng(1)
    dropout = rng.normal(0.5, 0.15, (6, 4, models.n_components))
    t = E.track_input(models, E.TrackData(tuple(f"im{k}" for k in range(6)), np.zeros((6, 2)),
                                          np.array([1.0, 0.0]), 0.0, dropout), var_floor=1e-6)
    got = np.exp(registry.get(KEY).fuse(t))
    np.testing.assert_allclose(got, literal_view_independent(models.Y, dropout), atol=1e-9, rtol=0)
    # the test-domain variance the GP methods add to a test measurement is added here too
    extra = rng.uniform(0.0, 0.02, (3, models.n_components))
    t2 = E.track_input(models.with_test_variance(extra), t_track(t, dropout), var_floor=1e-6)
    np.testing.assert_allclose(np.exp(registry.get(KEY).fuse(t2)),
                               literal_view_independent(models.Y, dropout, test_var=extra), atol=1e-9, rtol=0)
    single = np.exp(registry.get(KEY).single_view(t))
    for k in range(6):
        np.testing.assert_allclose(single[k], literal_view_independent(models.Y, dropout[k:k + 1])[0], atol=1e-9)


def t_track(t, dropout):
    return E.TrackData(tuple(f"im{k}" for k in range(len(dropout))), np.zeros((len(dropout), 2)),
                       np.array([1.0, 0.0]), 0.0, dropout)


def test_it_is_a_registered_pose_free_baseline_paired_with_with_uncertainty():
    m = registry.get(KEY)
    assert m is not None and not m.uses_poses and m.needs == frozenset({"gp"})
    assert ("with_uncertainty", KEY) in registry.comparisons()
    assert "other numbers" in registry.get("simple_bayes").note     # the report says what Simple Bayes reads


def test_it_cannot_separate_classes_that_differ_only_by_viewpoint():
    # ring_models: every class has the same mean over the circle; only the bearing of the peak differs
    models = ring_models(C=3, F=2)
    track = make_track(models, truth=1, K=6, n_s=4, seed=3)
    est = track.cam_xy[None]
    out = E.fuse_track(models, track, est, est[:, None], var_floor=1e-6)
    vi, mb = np.exp(out[KEY][0, -1]), np.exp(out["model_based"][0, -1])
    assert mb.argmax() == 1 and mb[1] > 0.9                  # the viewpoint model tells them apart
    assert vi.max() - vi.min() < 0.2                          # the view-independent model hardly can
