"""The diagonal and sparse forms of the basis route (pipeline/method/circle_basis.py): training
views evenly spaced on the circle, as BigBIRD's turntable gives them. The engine equals the
reference engine (tests/support/reference_fusion.py) to 1e-9 on the log posteriors there, at the
smallest noise variances, and the stated bound on the dropped entries of Q holds."""
import numpy as np
import pytest

from pipeline.method import circle_basis as cb
from pipeline.method import engine
from pipeline.method.fusion import engine_device, fuse_model_based, fuse_with_uncertainty
from pipeline.method.gp import GPClassModels
from tests.support import reference_fusion as ref
from tests.pipeline.method.test_engine import assert_log_close, random_tracks


def turntable_models(rng, C, F, *, n=120, ell=(0.06, 1.5), noise=(1e-5, 1e-3), amp=(1e-4, 0.3), drop=0):
    X, Y = [], []
    for c in range(C):
        th = np.linspace(-np.pi, np.pi, n, endpoint=False) + rng.uniform(-np.pi, np.pi)
        th = np.delete(th, rng.choice(n, drop, replace=False)) if drop else th
        X.append(np.c_[np.cos(th), np.sin(th)])
        Y.append(np.stack([0.25 + 0.1 * np.sin((f + 1) * th + c) + 0.02 * rng.standard_normal(len(th))
                           for f in range(F)]))
    lo, le = np.log(noise), np.log(ell)
    return GPClassModels([f"k{c}" for c in range(C)], list(range(F)), X, Y,
                         np.array([[y.mean() for y in Yc] for Yc in Y]), rng.uniform(*amp, (C, F)),
                         np.exp(rng.uniform(le[0], le[1], (C, F))), np.exp(rng.uniform(lo[0], lo[1], (C, F))))


@pytest.mark.parametrize("seed", range(4))
def test_turntable_forms_equal_the_reference(seed):
    rng = np.random.default_rng(40 + seed)
    C, F = 3, 3
    K = [1, 5, 9, 12][seed]
    S = [1, 4, 10, 7][seed]
    models = turntable_models(rng, C, F)
    # short and long length scales side by side: P ≤ N (diagonal) and P > N (sparse, aliased orders)
    models.length_scale[0, 0], models.length_scale[1, 1] = 0.065, 1.2
    routes = engine.plan(models).routes()
    assert routes["exact"] == 0 and routes["diagonal"] >= 1
    assert routes["basis"] - routes["diagonal"] >= 1     # at least one sparse form with P > N
    X, Z = random_tracks(rng, 3, 6, K, S, F, wrap=seed % 2 == 1)
    for vf in (1e-6, 1e-3):
        assert_log_close(fuse_with_uncertainty(models, X, Z, var_floor=vf, return_log=True, progress=False),
                         ref.fuse_with_uncertainty(models, X, Z, var_floor=vf, return_log=True, progress=False))
    meas = Z.mean(axis=2)
    assert_log_close(fuse_model_based(models, X[:, 0], meas, return_log=True, progress=False),
                     ref.fuse_model_based(models, X[:, 0], meas, return_log=True, progress=False))


def test_incomplete_ring_keeps_the_dense_form():
    rng = np.random.default_rng(2)
    models = turntable_models(rng, 2, 2, ell=(0.4, 1.0), drop=3)   # three views missing
    routes = engine.plan(models).routes()
    assert routes["basis"] == 4 and routes["diagonal"] == 0
    assert all(g.idx is None for row in engine.plan(models).basis for g in row)


@pytest.mark.parametrize("ell", [0.065, 0.09, 0.12, 0.3, 1.0])
def test_sparse_form_bound_holds(ell):
    """The covariance from the kept entries of Q against the one from all of Q, over many angle
    pairs including ±π: the difference stays within the stated bound (and that within SPARSE_TOL)."""
    rng = np.random.default_rng(9)
    th = np.linspace(-np.pi, np.pi, 120, endpoint=False) + 0.3
    x = np.c_[np.cos(th), np.sin(th)]
    y = 0.3 + 0.1 * np.sin(2 * th) + 0.01 * rng.standard_normal(120)
    a, noise = 0.05, 1e-5
    kappa = 1 / ell ** 2
    M, _ = cb.tail_order(kappa)
    P = 2 * M + 1
    g = cb.build(x, y, float(y.mean()), a, ell, noise)
    assert g is not None and g.idx is not None
    assert g.sparse_bound <= cb.SPARSE_TOL
    # the full Q, recomputed as build does, for the comparison
    from scipy.linalg import solve_triangular
    d_half = np.sqrt(cb.prior_weights(a, kappa, M))
    Xm = cb.features(x, P) * (d_half / np.sqrt(noise))
    A = Xm.T @ Xm + np.eye(P)
    Q = solve_triangular(np.linalg.cholesky(A), np.diag(d_half), lower=True)
    t = np.r_[rng.uniform(-np.pi, np.pi, 300), [np.pi, -np.pi, 0.3]]
    phi = cb.features(np.c_[np.cos(t), np.sin(t)], P)
    z_full = phi @ Q.T
    z_sparse = np.einsum("npt,pt->np", phi[:, g.idx], g.val)
    diff = np.abs(z_sparse @ z_sparse.T - z_full @ z_full.T) / a
    assert diff.max() <= g.sparse_bound + 1e-16
    if g.q2 is not None:   # the diagonal form's weighted Gram is the same matrix
        np.testing.assert_allclose((phi * g.q2) @ phi.T, z_sparse @ z_sparse.T, rtol=0, atol=1e-16 * a * P)


def test_extreme_posteriors_and_many_components_equal_the_reference():
    """Confident tracks (log posteriors below -700: the recursion's log-space branch) with 40
    components of tiny variances (a long product of variances per step)."""
    rng = np.random.default_rng(11)
    models = turntable_models(rng, 2, 40, n=60, ell=(0.3, 1.0), noise=(1e-5, 2e-5), amp=(1e-3, 3e-3))
    X, Z = random_tracks(rng, 2, 3, 6, 3, 40)
    Z[:, :, :, :] += 0.3 * np.arange(40) % 0.2       # far from both classes' means: confident
    a = fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    b = ref.fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    assert b.min() < -700                              # the log-space branch was needed
    assert_log_close(a, b)


def test_torch_path_equals_numpy_on_the_turntable_forms():
    rng = np.random.default_rng(5)
    models = turntable_models(rng, 2, 2)
    models.length_scale[0, 0] = 0.07                    # a sparse form (dense Q rebuilt for torch)
    X, Z = random_tracks(rng, 2, 4, 7, 5, 2)
    a = fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    with engine_device("torch-cpu"):
        b = fuse_with_uncertainty(models, X, Z, return_log=True, progress=False)
    assert_log_close(b, a)


def test_variance_product_is_folded_before_it_leaves_the_normal_range():
    from pipeline.method import kernels

    rng = np.random.default_rng(3)
    B, K, S = 4, 3, 2
    cov = np.broadcast_to(np.eye(K) * 1e-3, (B, K, K)).copy()
    args = (cov, np.empty((0, 0, 0)), np.empty(0), np.zeros((0, 1), dtype=np.int64), np.zeros((0, 1)), 0.0,
            rng.random((B, K)), rng.random((1, K)), np.full((1, K), 1e-4), rng.random((1, K, S)), B)
    ll0, vp0 = np.zeros((B, K, S)), np.ones((B, K))
    kernels.wu_loglik(*args, ll0, vp0)
    ll1, vp1 = np.zeros((B, K, S)), np.full((B, K), 1e-249)   # one more factor < 1e-250: folded
    kernels.wu_loglik(*args, ll1, vp1)
    assert np.all(vp1 == vp0)                                  # restarted from the new factor
    np.testing.assert_allclose(ll1, ll0 - 0.5 * np.log(1e-249), rtol=1e-15)
