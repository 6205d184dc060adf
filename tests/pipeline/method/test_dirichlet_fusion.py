"""Dirichlet fusion (Tchuiev & Indelman 2018, Algorithm 1): pipeline/method/dirichlet_fusion.py and
its place in a population cell (pipeline/evaluation/grid/population.py)."""
from __future__ import annotations

import itertools
import zlib

import numpy as np
import pytest
from scipy import stats

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.grid import population as P
from pipeline.method import dirichlet_fusion as DF
from pipeline.method.dirichlet import DirichletModels, prepare
from pipeline.method.methods.dirichlet import DIRICHLET
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models

D = 5


def models(C=4, seed=0):
    rng = np.random.default_rng(seed)
    return DirichletModels([f"c{c}" for c in range(C)], rng.uniform(0.5, 3.0, size=(C, D)), floor=1e-6)


def samples(K, n_s, seed=1):
    return np.random.default_rng(seed).dirichlet(np.full(D, 1.5), size=(K, n_s))


def test_keep_every_pair_equals_brute_force_all_pairs():
    m, g = models(), samples(K=3, n_s=3)
    prior = np.array([0.1, 0.2, 0.3, 0.4])
    log_mean, std = DF.fuse_dirichlet(m, g, n_ss=10**6, rng=None, prior=prior)
    theta = m.theta
    for k in range(3):
        lams = []
        for combo in itertools.product(range(3), repeat=k + 1):   # one dropout sample per view
            lam = prior.copy()
            for j, t in enumerate(combo):
                lam = lam * np.array([stats.dirichlet.pdf(prepare(g[j, t], 1e-6), th) for th in theta])
            lams.append(lam / lam.sum())
        lams = np.array(lams)
        np.testing.assert_allclose(np.exp(log_mean[k]), lams.mean(axis=0), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(std[k], lams.std(axis=0), rtol=1e-9, atol=1e-14)


def test_single_point_clouds_give_the_product_of_dirichlet_likelihoods():
    m, g = models(), samples(K=6, n_s=1)
    log_mean, std = DF.fuse_dirichlet(m, g, n_ss=1, rng=np.random.default_rng(0))
    like = np.array([[stats.dirichlet.logpdf(prepare(g[k, 0], 1e-6), th) for th in m.theta] for k in range(6)])
    cum = np.cumsum(like, axis=0)
    want = cum - np.log(np.exp(cum - cum.max(1, keepdims=True)).sum(1, keepdims=True)) - cum.max(1, keepdims=True)
    np.testing.assert_allclose(log_mean, want, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(std, 0.0)


def test_candidate_order_does_not_change_the_posterior_even_when_subsampling():
    m, g = models(C=4), samples(K=5, n_s=10)
    perm = [2, 0, 3, 1]
    a, sa = DF.fuse_dirichlet(m, g, n_ss=20, rng=np.random.default_rng(9))
    b, sb = DF.fuse_dirichlet(m.subset([m.classes[i] for i in perm]), g, n_ss=20, rng=np.random.default_rng(9))
    np.testing.assert_allclose(b, a[:, perm], rtol=0, atol=1e-12)
    np.testing.assert_allclose(sb, sa[:, perm], rtol=0, atol=1e-12)


def test_cloud_is_subsampled_to_n_ss_and_seeded():
    m, g = models(), samples(K=4, n_s=10)
    loglik = m.log_likelihood(g)
    cloud = np.full((1, 4), -np.log(4))
    sizes = []
    for k in range(4):
        cloud = DF.cloud_update(cloud, loglik[k], 30, np.random.default_rng(k))
        sizes.append(len(cloud))
        np.testing.assert_allclose(np.exp(cloud).sum(1), 1.0)
    assert sizes == [10, 30, 30, 30]
    x = DF.fuse_dirichlet(m, g, n_ss=30, rng=np.random.default_rng(4))
    y = DF.fuse_dirichlet(m, g, n_ss=30, rng=np.random.default_rng(4))
    z = DF.fuse_dirichlet(m, g, n_ss=30, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(x[0], y[0])
    assert not np.array_equal(x[0], z[0])
    with pytest.raises(ValueError, match="random generator"):
        DF.cloud_update(cloud, loglik[0], 30, None)


def test_single_view_is_one_step_of_the_recursion():
    m, g = models(), samples(K=3, n_s=4)
    one = DF.single_view(m, g)
    for k in range(3):
        np.testing.assert_allclose(one[k], DF.fuse_dirichlet(m, g[k:k + 1], n_ss=100, rng=None)[0][0], atol=1e-13)


def _cell(track, dm, seed=0, variant="default"):
    settings = (P.Setting("biased", "b", 0.1, (0.05, 0.0), 1, 3),
                P.Setting("randomized", "r", 0.2, (0.0, 0.0), 4, 3))
    dm.n_ss = 7
    return P.Cell(variant, "c1", 2, "scan", ("c0", "c1", "c2"), (0, 1), 1, track, settings, seed, 1e-6,
                  models={DIRICHLET: dm})


def test_cell_adds_the_dirichlet_same_for_every_realization_setting_and_variant():
    gp = ring_models()
    base = make_track(gp, truth=1, K=5, n_s=4)
    probs = np.random.default_rng(2).dirichlet(np.ones(D), size=(base.k, 4))
    track = E.TrackData(base.images, base.cam_xy, base.obj_xy, base.yaw, base.dropout, probs=probs)
    dm = models(C=3)
    banks = {"default": gp, "abl": gp}
    res = P.run_cell(banks, _cell(track, dm))
    want, std = DF.fuse_dirichlet(dm, probs, n_ss=7, rng=np.random.default_rng([0, zlib.crc32(b"c1"), 2, zlib.crc32(b"dirichlet")]))
    for posts in res["posts"].values():
        lp = posts[DIRICHLET]
        assert lp.shape == posts[E.WITH_UNCERTAINTY].shape
        for r in range(lp.shape[0]):
            np.testing.assert_array_equal(lp[r], want)
    np.testing.assert_array_equal(res["extras"][DIRICHLET]["std"], std)
    assert 0.0 <= res["difficulty"][DIRICHLET] <= 1.0
    # an ablation variant of the same cell sees the same Dirichlet (the method has no GP)
    other = P.run_cell(banks, _cell(track, dm, variant="abl"))
    np.testing.assert_array_equal(other["posts"][("biased", "b")][DIRICHLET], res["posts"][("biased", "b")][DIRICHLET])
    # without models or probability vectors the cell runs the other methods only
    assert DIRICHLET not in P.run_cell(banks, _cell(base, dm))["posts"][("biased", "b")]
