"""Property tests (hypothesis) of the fusion engine on random models, tracks and sample sets."""
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty, simple_bayes
from tests.pipeline.method.test_fusion import random_case

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])

shapes = st.fixed_dictionaries({
    "seed": st.integers(0, 10_000), "C": st.integers(2, 4), "F": st.integers(1, 3), "K": st.integers(1, 6),
    "Nx": st.integers(1, 5), "S": st.integers(1, 4), "unit_circle": st.booleans(),
})


def _is_distribution(p):
    assert not np.any(np.isnan(p))
    assert np.all(p >= 0) and np.all(p <= 1)
    np.testing.assert_allclose(p.sum(axis=-1), 1.0, atol=1e-12)


@SETTINGS
@given(shapes, st.lists(st.floats(0.01, 1.0), min_size=4, max_size=4))
def test_posteriors_are_distributions(s, prior_raw):
    models, samples, dropout = random_case(**s)
    prior = np.asarray(prior_raw[: s["C"]])
    for p in (fuse_with_uncertainty(models, samples, dropout, prior=prior),
              fuse_model_based(models, samples[0], dropout.mean(1), prior=prior),
              simple_bayes(np.abs(dropout.mean(1)[:, :1]) + np.arange(s["C"]), prior=prior)):
        assert p.shape == (s["K"], s["C"])
        _is_distribution(p)


@SETTINGS
@given(shapes, st.randoms(use_true_random=False))
def test_permuting_classes_permutes_posterior(s, rnd):
    models, samples, dropout = random_case(**s)
    perm = list(range(s["C"]))
    rnd.shuffle(perm)
    permuted = models.select([models.classes[i] for i in perm])
    prior = np.linspace(1.0, 2.0, s["C"])
    a = fuse_with_uncertainty(models, samples, dropout, prior=prior)
    b = fuse_with_uncertainty(permuted, samples, dropout, prior=prior[perm])
    np.testing.assert_allclose(b, a[:, perm], atol=1e-12)
    a = fuse_model_based(models, samples[0], dropout.mean(1), prior=prior)
    b = fuse_model_based(permuted, samples[0], dropout.mean(1), prior=prior[perm])
    np.testing.assert_allclose(b, a[:, perm], atol=1e-12)
    scores = np.abs(dropout[:, 0, :1]) + np.linspace(0.1, 0.9, s["C"])
    np.testing.assert_allclose(simple_bayes(scores[:, perm], prior=prior[perm]),
                               simple_bayes(scores, prior=prior)[:, perm], atol=1e-12)


@SETTINGS
@given(shapes, st.sampled_from([0.0, 1e-9, 1e-7]))
def test_no_localization_or_model_uncertainty_gives_model_based(s, sigma):
    """σ -> 0 (all localization samples at the estimate) and identical dropout samples (no model
    uncertainty, v_z = 0): Model with Uncertainty becomes Model Based."""
    models, samples, dropout = random_case(**s)
    est = samples[0]
    rng = np.random.default_rng(s["seed"])
    near = est[None] + sigma * rng.standard_normal((s["Nx"],) + est.shape)
    same = np.repeat(dropout[:, :1], s["S"], axis=1)                  # every sample = the measurement
    mwu = fuse_with_uncertainty(models, near, same, var_floor=0.0)
    mb = fuse_model_based(models, est, same[:, 0])
    np.testing.assert_allclose(mwu, mb, atol=1e-10 if sigma == 0 else 1e-4)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.booleans())
def test_more_localization_samples_converge(seed, unit_circle):
    """The result is the mean of per-sample posteriors in [0, 1] (exactly: splitting the samples
    averages), so by Hoeffding |P_n - E P| <= sqrt(ln(2/δ) / 2n) with probability 1 - δ: the error
    bound shrinks like n^-1/2 and the estimates must respect it."""
    K, C = 4, 3
    models, _, dropout = random_case(seed, C=C, K=K, Nx=1, S=3, unit_circle=unit_circle)
    rng = np.random.default_rng(seed + 1)
    est = rng.uniform(-1.5, 1.5, (K, 2))

    def draw(n):
        x = est[None] + 0.3 * rng.standard_normal((n, K, 2))
        return x / np.linalg.norm(x, axis=-1, keepdims=True) if unit_circle else x

    ref_n = 10_000
    ref = fuse_with_uncertainty(models, draw(ref_n), dropout, progress=False)
    bound = lambda n: math.sqrt(math.log(2 / 1e-7) / (2 * n))  # noqa: E731
    errors = {}
    for n in (20, 500, 5000):
        x = draw(n)
        p = fuse_with_uncertainty(models, x, dropout)
        errors[n] = np.abs(p - ref).max()
        assert errors[n] <= bound(n) + bound(ref_n)
        half = n // 2
        lp = (fuse_with_uncertainty(models, x[:half], dropout) * half
              + fuse_with_uncertainty(models, x[half:], dropout) * (n - half)) / n
        np.testing.assert_allclose(lp, p, atol=1e-12)
    # With the bound at n = 5000 about 16x tighter than at n = 20, the large sample is the closer one
    # unless the small one is lucky; either way both are within their own bound (checked above).
    assert errors[5000] <= max(errors[20], bound(5000) + bound(ref_n))
