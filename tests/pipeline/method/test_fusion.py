"""The fusion engine against the literal Eq. 13-40, the shared vectors, and itself (objects, chunks)."""
from pathlib import Path

import numpy as np
import pytest

from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty, simple_bayes
from tests.support.reference_fusion import tri_inverse
from pipeline.method.geometry import relative_inputs, rot, sample_localization
from pipeline.method.gp import GPClassModels
from tests.support.fusion_methods import (Episode, ModelBased, ModelWithUncertainty, Observation, SimpleBayes,
                                  fuse_with_uncertainty_sampled, run_episodes)
from tests.support.literal_paper import literal_model_based, literal_uncertainty

VECTORS = Path(__file__).resolve().parents[2] / "support" / "data" / "fusion_cases.npz"
TOL = 1e-9


def random_case(seed, C=3, F=2, K=5, Nx=3, S=4, unit_circle=True, separation=0.1):
    """Random models (own training set per class), localization samples and dropout sets."""
    rng = np.random.default_rng(seed)
    X, Y = [], []
    for c in range(C):
        n = 14 + 2 * c
        if unit_circle:
            th = np.sort(rng.uniform(0, 2 * np.pi, n))
            x = np.c_[np.cos(th), np.sin(th)]
        else:
            x = rng.uniform(-2, 2, (n, 2))
            th = np.arctan2(x[:, 1], x[:, 0])
        X.append(x)
        Y.append(np.stack([0.25 + separation * np.sin((f + 1) * th + 2.0 * c) + 0.01 * rng.standard_normal(n)
                           for f in range(F)]))
    models = GPClassModels([f"k{c}" for c in range(C)], list(range(F)), X, Y,
                           np.array([[y.mean() for y in Yc] for Yc in Y]),
                           rng.uniform(0.003, 0.03, (C, F)), rng.uniform(0.4, 1.5, (C, F)),
                           rng.uniform(5e-4, 3e-3, (C, F)))
    est = rng.uniform(-1.5, 1.5, (K, 2))
    samples = est[None] + 0.2 * rng.standard_normal((Nx, K, 2))
    if unit_circle:
        samples /= np.linalg.norm(samples, axis=-1, keepdims=True)
    dropout = 0.25 + 0.05 * rng.standard_normal((K, S, F))
    return models, samples, dropout


def literal_args(models):
    return (models.X, models.Y, models.mean, models.amplitude, models.length_scale, models.noise)


def models_from_vectors(z, i):
    g = lambda n: z[f"case{i}_{n}"]  # noqa: E731
    C, F, _ = g("ST").shape
    return GPClassModels([f"c{j}" for j in range(C)], list(range(F)), [g("XT")] * C, list(g("ST")),
                         g("m"), g("amp"), g("ell"), g("sn2"))


@pytest.mark.parametrize("case", range(4))
def test_vectors_engine_and_literal(case):
    z = np.load(VECTORS)
    g = lambda n: z[f"case{case}_{n}"]  # noqa: E731
    models = models_from_vectors(z, case)
    rel, drop = g("rel_samples"), g("dropout")
    np.testing.assert_allclose(fuse_with_uncertainty(models, rel, drop), g("post_uncertainty"), rtol=0, atol=TOL)
    np.testing.assert_allclose(fuse_model_based(models, rel[0], drop.mean(axis=1)), g("post_model_based"),
                               rtol=0, atol=TOL)
    lit = literal_args(models)
    np.testing.assert_allclose(literal_uncertainty(*lit, rel, drop), g("post_uncertainty"), rtol=0, atol=TOL)
    np.testing.assert_allclose(literal_model_based(*lit, rel[0], drop.mean(axis=1)), g("post_model_based"),
                               rtol=0, atol=TOL)


@pytest.mark.parametrize("seed,unit_circle,prior", [(10, True, None), (11, False, None), (12, True, [0.5, 0.3, 0.2]),
                                                     (13, False, [0.1, 0.1, 0.8])])
def test_engine_matches_literal_on_random_cases(seed, unit_circle, prior):
    models, samples, dropout = random_case(seed, unit_circle=unit_circle)
    lit = literal_args(models)
    np.testing.assert_allclose(fuse_with_uncertainty(models, samples, dropout, prior=prior),
                               literal_uncertainty(*lit, samples, dropout, prior=prior), rtol=0, atol=TOL)
    meas = dropout.mean(axis=1)
    np.testing.assert_allclose(fuse_model_based(models, samples[0], meas, prior=prior),
                               literal_model_based(*lit, samples[0], meas, prior=prior), rtol=0, atol=TOL)


def test_engine_matches_literal_with_custom_variance_floor():
    models, samples, dropout = random_case(14, K=4, S=3)
    dropout[1] = dropout[1, :1]  # identical samples at one step: the floor decides v_z there
    lit = literal_args(models)
    for floor in (1e-6, 1e-3):
        np.testing.assert_allclose(fuse_with_uncertainty(models, samples, dropout, var_floor=floor),
                                   literal_uncertainty(*lit, samples, dropout, var_floor=floor), rtol=0, atol=TOL)


def test_simple_bayes_matches_product_rule():
    rng = np.random.default_rng(15)
    scores = rng.dirichlet(np.ones(4), size=6)
    prior = np.array([0.1, 0.2, 0.3, 0.4])
    expected, p = [], prior.copy()
    for s in scores:
        p = p * s / np.sum(p * s)
        expected.append(p)
    np.testing.assert_allclose(simple_bayes(scores, prior=prior), expected, rtol=0, atol=TOL)
    batch = np.stack([scores, scores[::-1]])
    out = simple_bayes(batch)
    np.testing.assert_allclose(out[1], simple_bayes(scores[::-1]), atol=1e-15)
    # A zero score cannot make 0/0, even when every class gets zero.
    z = np.zeros((3, 4))
    assert np.all(np.isfinite(simple_bayes(z))) and np.allclose(simple_bayes(z).sum(-1), 1)


def test_step_objects_equal_engine():
    models, samples, dropout = random_case(16, K=6, Nx=5, S=3)
    prior = [0.2, 0.5, 0.3]
    mwu = ModelWithUncertainty(models, prior=prior)
    mb = ModelBased(models, prior=prior)
    sb = SimpleBayes(models.classes, prior=prior)
    scores = np.abs(dropout[:, :, :1].mean(axis=1)) + np.linspace(0.1, 0.3, 3)  # any (K, C) scores
    for _ in range(2):  # reset() really forgets
        mwu.reset(), mb.reset(), sb.reset()
        a = np.array([mwu.update(Observation(inputs=samples[:, k], dropout=dropout[k])) for k in range(6)])
        b = np.array([mb.update(Observation(inputs=samples[0, k], dropout=dropout[k])) for k in range(6)])
        c = np.array([sb.update(Observation(scores=scores[k])) for k in range(6)])
        np.testing.assert_allclose(a, fuse_with_uncertainty(models, samples, dropout, prior=prior), atol=TOL)
        np.testing.assert_allclose(b, fuse_model_based(models, samples[0], dropout.mean(1), prior=prior), atol=TOL)
        np.testing.assert_allclose(c, simple_bayes(scores, prior=prior), atol=TOL)


def test_run_episodes_flat_metrics():
    models, samples, dropout = random_case(17, K=4, Nx=4, S=3)
    ep = [Episode([Observation(inputs=samples[:, k], dropout=dropout[k]) for k in range(4)], truth=t)
          for t in (0, "k2")]
    out = run_episodes(ModelWithUncertainty(models), ep, progress=False, return_posteriors=True)
    post = fuse_with_uncertainty(models, samples, dropout)
    assert out["episodes"] == 2 and out["steps"] == 8
    assert out["p_truth_final"] == pytest.approx((post[-1, 0] + post[-1, 2]) / 2)
    assert out["p_truth_overall"] == pytest.approx((post[:, 0].mean() + post[:, 2].mean()) / 2)
    best = post.argmax(-1)
    assert out["correct_overall"] == pytest.approx(((best == 0).mean() + (best == 2).mean()) / 2)
    np.testing.assert_allclose(np.exp(out["log_posteriors"][0]), post, atol=TOL)


def test_batched_realizations_and_chunking_agree():
    models, samples, dropout = random_case(18, K=5, Nx=7, S=3)
    _, samples2, dropout2 = random_case(19, K=5, Nx=7, S=3)
    X = np.stack([samples, samples2, samples[::-1]])
    Z = np.stack([dropout, dropout2, dropout2])
    whole = fuse_with_uncertainty(models, X, Z)
    assert whole.shape == (3, 5, 3)
    for r in range(3):
        np.testing.assert_allclose(whole[r], fuse_with_uncertainty(models, X[r], Z[r]), atol=1e-13)
    # Tiny blocks: several realizations per block, and one realization split across blocks.
    for block in (1, 2000, 6000):
        for threads in (1, 2):
            np.testing.assert_allclose(fuse_with_uncertainty(models, X, Z, block=block, threads=threads,
                                                             progress=False), whole, atol=1e-13)
    M = Z.mean(axis=2)
    mb = fuse_model_based(models, X[:, 0], M)
    np.testing.assert_allclose(fuse_model_based(models, X[:, 0], M, block=1, threads=2, progress=False), mb,
                               atol=1e-13)
    for r in range(3):
        np.testing.assert_allclose(mb[r], fuse_model_based(models, X[r, 0], M[r]), atol=1e-13)


def test_confident_posteriors_never_nan():
    models, samples, dropout = random_case(20, K=60, Nx=4, S=5, separation=0.3)
    # Dropout samples right on class 1's predictive means make the other classes vanishingly unlikely.
    truth_means = models.predict(samples[0])[0][1]                         # (F, K)
    dropout = truth_means.T[:, None, :] + 1e-3 * np.random.default_rng(0).standard_normal((60, 5, 2))
    for out, lout in ((fuse_with_uncertainty(models, samples, dropout),
                       fuse_with_uncertainty(models, samples, dropout, return_log=True)),
                      (fuse_model_based(models, samples[0], dropout.mean(1)),
                       fuse_model_based(models, samples[0], dropout.mean(1), return_log=True))):
        assert not np.any(np.isnan(out)) and np.allclose(out.sum(-1), 1)
        assert np.all(np.isfinite(lout)) and np.min(lout) < -745        # exp underflows, the log does not
        assert out[-1, 1] > 1 - 1e-12


def test_sampled_layer_is_thin():
    models, _, dropout = random_case(21, K=4, S=3)
    est = np.array([[2.0, 0.5], [1.5, 1.5], [0.2, 2.0], [-1.0, 1.8]])
    obj, yaw = np.array([0.1, -0.2]), 0.7
    out = fuse_with_uncertainty_sampled(models, est, 0.3, dropout, obj_xy=obj, yaw=yaw, n_samples=6, seed=3)
    manual = relative_inputs(sample_localization(est, 0.3, 6, np.random.default_rng(3)), obj, yaw)
    np.testing.assert_allclose(out, fuse_with_uncertainty(models, manual, dropout), atol=1e-15)


def test_geometry_frames():
    # Object at (1, 1) with yaw 90°: a camera at (1, 3) is 2 m along world +y, which is the
    # object's own +x axis (Rot(-90°) maps +y to +x).
    r = relative_inputs([1.0, 3.0], [1.0, 1.0], np.pi / 2, unit_circle=False)
    np.testing.assert_allclose(r, [2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(relative_inputs([1.0, 3.0], [1.0, 1.0], np.pi / 2), [1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(rot(0.3) @ rot(-0.3), np.eye(2), atol=1e-15)
    with pytest.raises(ValueError, match="coincide"):
        relative_inputs([[1.0, 1.0]], [1.0, 1.0], 0.0)
    est = np.zeros((4, 2))
    s = sample_localization(est, 0.5, 20000, 1)
    assert s.shape == (20000, 4, 2)
    assert abs(s.std() - 0.5) < 0.01 and abs(s.mean()) < 0.01
    np.testing.assert_array_equal(s, sample_localization(est, 0.5, 20000, 1))
    assert sample_localization(np.zeros((3, 4, 2)), 0.1, 5, 0).shape == (3, 5, 4, 2)
    np.testing.assert_array_equal(sample_localization(est + 1, 0.0, 3, 0), np.ones((3, 4, 2)))
    with pytest.raises(ValueError, match="NaN"):
        sample_localization(np.full((2, 2), np.nan), 0.1, 3, 0)


def test_tri_inverse():
    rng = np.random.default_rng(22)
    A = rng.standard_normal((5, 7, 7))
    L = np.linalg.cholesky(A @ A.transpose(0, 2, 1) + 7 * np.eye(7))
    M = tri_inverse(L)
    np.testing.assert_allclose(M @ L, np.broadcast_to(np.eye(7), M.shape), atol=1e-13)
    assert np.all(np.triu(M, 1) == 0)


def test_bad_shapes_and_values_raise():
    models, samples, dropout = random_case(23, K=3)
    with pytest.raises(ValueError, match="dropout must be"):
        fuse_with_uncertainty(models, samples, dropout[:2])
    with pytest.raises(ValueError, match="inputs must be"):
        fuse_with_uncertainty(models, samples[..., :1], dropout)
    bad = dropout.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fuse_with_uncertainty(models, samples, bad)
    with pytest.raises(ValueError, match="prior"):
        fuse_model_based(models, samples[0], dropout.mean(1), prior=[1, -1, 1])
    with pytest.raises(ValueError, match="measurements must be"):
        fuse_model_based(models, samples[0], dropout.mean(1)[:, :1])
    with pytest.raises(ValueError, match="localization samples"):
        m = ModelWithUncertainty(models)
        m.update(Observation(inputs=samples[:, 0], dropout=dropout[0]))
        m.update(Observation(inputs=samples[:2, 1], dropout=dropout[1]))
