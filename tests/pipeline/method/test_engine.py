"""The fast engine (pipeline/method/engine.py, circle_basis.py) equals the reference engine
(tests/support/reference_fusion.py, the engine before it) on random cases, on both of its routes."""
import math

import numpy as np
import pytest

from pipeline.method import circle_basis as cb
from pipeline.method import engine
from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty
from pipeline.method.gp import GPClassModels
from tests.support import reference_fusion as ref

RTOL = ATOL = 1e-9   # on log posteriors: |new - ref| <= 1e-9 * max(1, |ref|)


def random_models(rng, C, F, *, noise=(1e-5, 3e-3), amp=(0.003, 0.1), ell=(0.25, 1.5), on_circle=True,
                  n_train=(20, 130)):
    X, Y = [], []
    for c in range(C):
        n = int(rng.integers(*n_train))
        if rng.random() < 0.5:   # a turntable ring with a few views missing, or scattered views
            th = np.linspace(-np.pi, np.pi, n, endpoint=False) + rng.uniform(-np.pi, np.pi)
            th = th[rng.random(n) > 0.1]
        else:
            th = np.sort(rng.uniform(-np.pi, np.pi, n))
        x = np.c_[np.cos(th), np.sin(th)]
        if not on_circle:
            x *= rng.uniform(0.5, 2.0, (len(x), 1))
        X.append(x)
        Y.append(np.stack([0.25 + 0.1 * np.sin((f + 1) * th + c) + 0.01 * rng.standard_normal(len(th))
                           for f in range(F)]))
    lo = np.log(noise)
    return GPClassModels([f"k{c}" for c in range(C)], list(range(F)), X, Y,
                         np.array([[y.mean() for y in Yc] for Yc in Y]), rng.uniform(*amp, (C, F)),
                         rng.uniform(*ell, (C, F)), np.exp(rng.uniform(lo[0], lo[1], (C, F))))


def random_tracks(rng, R, Nx, K, S, F, *, wrap=False, unit=True):
    th0 = rng.uniform(-np.pi, np.pi, (R, 1, K))
    if wrap:   # estimates straddling ±π, some exactly at it
        th0 = np.pi * rng.choice([-1.0, 1.0], (R, 1, K)) + rng.uniform(-0.05, 0.05, (R, 1, K))
        th0[..., 0] = np.pi
    th = th0 + 0.2 * rng.standard_normal((R, Nx, K))
    x = np.stack([np.cos(th), np.sin(th)], -1)
    if not unit:
        x *= rng.uniform(0.5, 2.0, (R, Nx, K, 1))
    drop = 0.25 + 0.05 * rng.standard_normal((R, K, S, F))
    return x, drop


def assert_log_close(new, old):
    np.testing.assert_allclose(new, old, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("seed", range(8))
def test_random_cases_equal_the_reference(seed):
    rng = np.random.default_rng(100 + seed)
    C, F = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    K = [1, 2, 3, 5, 7, 9, 11, 12][seed]
    S = int(rng.integers(1, 11))
    models = random_models(rng, C, F)
    X, Z = random_tracks(rng, 3, 7, K, S, F, wrap=seed % 2 == 1)
    prior = None if seed % 3 else rng.dirichlet(np.ones(C))
    assert engine.plan(models).routes()["basis"] > 0
    for vf in (1e-6, 1e-3):
        assert_log_close(fuse_with_uncertainty(models, X, Z, prior=prior, var_floor=vf, return_log=True, progress=False),
                         ref.fuse_with_uncertainty(models, X, Z, prior=prior, var_floor=vf, return_log=True,
                                                   progress=False))
    meas = Z.mean(axis=2)
    assert_log_close(fuse_model_based(models, X[:, 0], meas, prior=prior, return_log=True, progress=False),
                     ref.fuse_model_based(models, X[:, 0], meas, prior=prior, return_log=True, progress=False))


@pytest.mark.parametrize("case", ["off_circle_inputs", "off_circle_training", "short_length_scale", "3d"])
def test_exact_route_equals_the_reference(case):
    rng = np.random.default_rng(7)
    C, F, K, S = 3, 2, 6, 4
    models = random_models(rng, C, F, on_circle=case != "off_circle_training",
                           ell=(0.03, 0.06) if case == "short_length_scale" else (0.3, 1.0))
    X, Z = random_tracks(rng, 2, 5, K, S, F, unit=case != "off_circle_inputs")
    if case == "3d":
        models = GPClassModels(models.classes, models.components, [np.c_[x, 0.3 * x[:, :1]] for x in models.X],
                               models.Y, models.mean, models.amplitude, models.length_scale, models.noise)
        X = np.concatenate([X, 0.3 * X[..., :1]], axis=-1)
    routes = engine.plan(models).routes()
    if case in ("off_circle_training", "short_length_scale", "3d"):
        assert routes["basis"] == 0
    else:
        assert routes["basis"] > 0     # the bank could, but these inputs are not unit vectors
    assert_log_close(fuse_with_uncertainty(models, X, Z, return_log=True, progress=False),
                     ref.fuse_with_uncertainty(models, X, Z, return_log=True, progress=False))
    assert_log_close(fuse_model_based(models, X[:, 0], Z.mean(2), return_log=True, progress=False),
                     ref.fuse_model_based(models, X[:, 0], Z.mean(2), return_log=True, progress=False))


def test_predictive_equals_gp_predict_on_both_routes():
    rng = np.random.default_rng(3)
    models = random_models(rng, 3, 3, ell=(0.05, 1.5))    # some GPs too short for the basis route
    routes = engine.plan(models).routes()
    assert routes["basis"] and routes["exact"]
    X, _ = random_tracks(rng, 4, 6, 8, 1, 3)
    X = X.reshape(-1, 8, 2)
    mu, cov = engine.predictive(models, X)
    mu0, cov0 = models.predict(X)
    scale = (models.amplitude + models.noise)[None, :, :, None, None]
    np.testing.assert_allclose(mu, mu0, rtol=0, atol=1e-12)
    assert np.max(np.abs(cov - cov0) / scale) < 1e-12


@pytest.mark.parametrize("ell", [0.05, 0.1, 0.3, 1.0, 3.0])
def test_truncation_bound_holds_at_the_worst_case(ell):
    """At zero angle difference every dropped term of the Bessel series is positive and adds up:
    the truncated kernel's error there is the whole tail τ_M, the largest over all angles."""
    kappa = 1.0 / ell ** 2
    M, tau = cb.tail_order(kappa)
    assert tau <= cb.KERNEL_TOL
    d = cb.prior_weights(1.0, kappa, M)            # a = 1: k(x, x) = 1 exactly
    phi = cb.features(np.array([[1.0, 0.0]]), 2 * M + 1)[0]
    err = 1.0 - float(np.sum(d * phi * phi))
    assert err <= tau + 4e-16                        # the bound, plus rounding of the sum
    # one order less would break the tolerance: M is the smallest (τ_{M-1} = τ_M + 2 ive(M, κ))
    from scipy.special import ive
    assert 2 * ive(M, kappa) + tau > cb.KERNEL_TOL or M == 0


def test_kernel_truncation_error_over_all_angles():
    rng = np.random.default_rng(0)
    for ell in (0.2, 0.5, 1.0):
        kappa = 1 / ell ** 2
        M, tau = cb.tail_order(kappa)
        th = np.r_[rng.uniform(-np.pi, np.pi, 400), [0.0, np.pi, -np.pi]]
        x = np.c_[np.cos(th), np.sin(th)]
        phi = cb.features(x, 2 * M + 1)
        approx = (phi * cb.prior_weights(1.0, kappa, M)) @ phi.T
        exact = np.exp(-kappa * (1 - np.cos(th[:, None] - th[None, :])))
        # plus rounding: the sums of ~P terms near 1, and exp(-κ(1 - cos Δ)) carries about κ·ε itself
        assert np.max(np.abs(approx - exact)) <= tau + (8 + 4 * kappa) * 2.2e-16


def test_features_are_cos_and_sin_of_multiples():
    th = np.array([-np.pi, -1.0, 0.0, 0.3, np.pi])
    phi = cb.features(np.c_[np.cos(th), np.sin(th)], 9)
    want = np.concatenate([np.ones((5, 1))] + [np.c_[np.cos(n * th), np.sin(n * th)] for n in range(1, 5)], 1)
    np.testing.assert_allclose(phi, want, atol=1e-14)


def test_non_positive_definite_names_the_gp(monkeypatch):
    from pipeline.method import kernels

    K = 3
    bad = np.broadcast_to(np.eye(K), (4, K, K)).copy()
    bad[2] = -np.eye(K)                                # trajectory 2 of this GP is not PD
    empty3, no_w = np.empty((0, 0, 0)), np.empty(0)
    no_idx, no_val = np.zeros((0, 1), dtype=np.int64), np.zeros((0, 1))
    args = (bad, empty3, no_w, no_idx, no_val, 0.0, np.zeros((4, K)))
    assert kernels.mb_loglik(*args, np.zeros((4, K)), np.zeros((4, K, 1)), np.ones((4, K))) == 2
    assert kernels.wu_loglik(*args, np.zeros((2, K)), np.ones((2, K)), np.zeros((2, K, 3)), 2,
                             np.zeros((4, K, 3)), np.ones((4, K))) == 2
    # a PD one: L = 2 I, so y = M d = d / 2 and the Model Based term is -y²/2 per step, var 4
    ll, vp = np.zeros((4, K, 1)), np.ones((4, K))
    assert kernels.mb_loglik(4 * bad * bad, empty3, no_w, no_idx, no_val, 0.0, np.zeros((4, K)), np.ones((4, K)),
                             ll, vp) == -1
    np.testing.assert_allclose(ll, -0.125)
    np.testing.assert_allclose(vp, 4.0)

    rng = np.random.default_rng(1)
    models = random_models(rng, 2, 2)
    X, Z = random_tracks(rng, 1, 4, K, 3, 2)

    def per_gp(models_, X_):
        cov = np.broadcast_to(np.eye(K), (len(X_), K, K)).copy()
        cov[-1] = -np.eye(K)
        yield 1, 0, np.zeros((len(X_), K)), cov, empty3, no_w, no_idx, no_val, 0.0

    monkeypatch.setattr(engine, "per_gp", per_gp)
    with pytest.raises(ValueError, match=r"not positive definite for \(class, component\) \[\('k1', 0\)\]"):
        fuse_with_uncertainty(models, X, Z, progress=False)
    with pytest.raises(ValueError, match=r"not positive definite for \(class, component\) \[\('k1', 0\)\]"):
        fuse_model_based(models, X[:, 0], Z.mean(2), progress=False)


def test_threads_and_blocks_do_not_change_results():
    rng = np.random.default_rng(5)
    models = random_models(rng, 3, 2)
    X, Z = random_tracks(rng, 5, 9, 6, 3, 2)
    base = fuse_with_uncertainty(models, X, Z, return_log=True, progress=False, threads=1)
    for block, threads in ((1, 2), (700, 2), (1 << 22, 1)):
        np.testing.assert_allclose(fuse_with_uncertainty(models, X, Z, return_log=True, progress=False,
                                                         block=block, threads=threads), base, rtol=1e-14, atol=1e-13)
    assert math.isfinite(float(base.sum()))
