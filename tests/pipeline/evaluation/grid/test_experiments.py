"""The paper's section 5.5 experiments as pure functions, on small hand-made class models."""
import numpy as np
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.method.fusion import fuse_model_based
from pipeline.method.gp import GPClassModels
from pipeline.method.methods.view_independent import KEY as VIEW_INDEPENDENT, class_gaussians
from tests.support.params import PARAMS


def ring_models(n=24, F=2, C=3, lift=()):
    """Class c's component f peaks at a class-specific bearing: views disambiguate classes
    (``lift``: per-class offsets of the targets, which set classes apart without views too)."""
    th = np.linspace(-np.pi, np.pi, n, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], 1)
    Y = []
    for c in range(C):
        up = lift[c] if c < len(lift) else 0.0
        Y.append(np.stack([0.5 + up + 0.4 * np.cos(th - (2 * np.pi * c / C) - f) for f in range(F)]))
    ones = np.ones((C, F))
    return GPClassModels([f"c{c}" for c in range(C)], list(range(F)), [X] * C, Y,
                         0.5 * ones, 0.08 * ones, 0.7 * ones, 1e-3 * ones)


def make_track(models, truth=0, K=6, n_s=5, seed=0):
    rng = np.random.default_rng(seed)
    obj = np.array([1.0, 2.0])
    yaw = 0.4
    ang = np.linspace(0.2, 2.2, K)
    cam = obj + 1.5 * np.stack([np.cos(ang + yaw), np.sin(ang + yaw)], 1)
    tr = E.TrackData(images=tuple(f"im{k}" for k in range(K)), cam_xy=cam, obj_xy=obj, yaw=yaw,
                     dropout=np.zeros((K, n_s, models.n_components)))
    mu, _ = models.marginal(tr.inputs(cam))                     # (K, C, F)
    drop = mu[:, truth, None, :] + rng.normal(0, 0.02, (K, n_s, models.n_components))
    return E.TrackData(tr.images, cam, obj, yaw, drop)


def test_inputs_are_unit_vectors_in_the_object_frame():
    m = ring_models()
    tr = make_track(m)
    u = tr.inputs(tr.cam_xy)
    np.testing.assert_allclose(np.linalg.norm(u, axis=-1), 1.0)
    # Object frame: bearing of the camera relative to the object, minus the yaw.
    rel = tr.cam_xy - tr.obj_xy
    np.testing.assert_allclose(np.arctan2(u[:, 1], u[:, 0]),
                               np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - tr.yaw))))


def test_no_error_both_methods_find_the_truth():
    m = ring_models()
    tr = make_track(m, truth=1)
    posts = E.biased(m, tr, (0.0, 0.0), 0.0, 3, np.random.default_rng(0), var_floor=1e-6)
    for key, p in posts.items():
        p = np.exp(p)
        assert p.shape == (1, tr.k, 3)
        np.testing.assert_allclose(p.sum(-1), 1.0)
        if key != VIEW_INDEPENDENT:
            assert p[0, -1].argmax() == 1, key


def test_view_independent_cannot_tell_classes_that_differ_only_in_viewpoint():
    """On the ring every class's targets are one cosine over a full turn at another phase: each
    class has mean 0.5 and the same variance, so the view-independent Gaussians are equal and the
    posterior is uniform; its argmax is the last bit of rounding (class 1 on one processor, 0 on
    another), so the uniform answer itself is asserted. Bound: the class means and
    variances are sums of n = 24 targets (error <= n·eps·max|y|); each of the K·F log densities
    moves by at most (2|d|/v + d²/v² + 1/v) times that."""
    m = ring_models()
    tr = make_track(m, truth=1)
    p = np.exp(E.biased(m, tr, (0.0, 0.0), 0.0, 3, np.random.default_rng(0), var_floor=1e-6)[VIEW_INDEPENDENT])
    mean, var = class_gaussians(m, 1e-6)
    d = np.abs(tr.measurement[:, None, :] - mean[None]).max()
    v = var.min()
    n, eps = m.Y[0].shape[1], np.finfo(float).eps
    per_density = (2 * d / v + d * d / (v * v) + 1 / v) * n * eps * np.abs(np.concatenate(m.Y)).max()
    tol = tr.k * m.n_components * per_density
    assert tol < 1e-9                                  # far below any real preference
    np.testing.assert_allclose(p, 1 / 3, rtol=0, atol=tol)


def test_view_independent_finds_a_class_its_mean_sets_apart():
    """The same ring with the truth's targets lifted by 0.3: now the view-independent Gaussians
    differ by far more than rounding and the method finds the truth."""
    m = ring_models(lift=(0.0, 0.3))
    tr = make_track(m, truth=1)
    p = np.exp(E.biased(m, tr, (0.0, 0.0), 0.0, 3, np.random.default_rng(0), var_floor=1e-6)[VIEW_INDEPENDENT])
    assert p[0, -1].argmax() == 1 and p[0, -1, 1] > 0.99


def test_model_based_uses_biased_estimates():
    m = ring_models()
    tr = make_track(m)
    bias = np.array([0.3, -0.2])
    posts = E.biased(m, tr, bias, 0.3, 4, np.random.default_rng(0), var_floor=1e-6)
    direct = fuse_model_based(m, tr.inputs(tr.cam_xy + bias), tr.measurement, progress=False)
    np.testing.assert_allclose(np.exp(posts[E.MODEL_BASED][0]), direct, atol=1e-12)


def test_randomized_is_deterministic_and_chunk_independent():
    m = ring_models()
    tr = make_track(m)
    a = E.randomized(m, tr, (0.1, 0.0), 0.2, 7, 5, np.random.default_rng(3), var_floor=1e-6, chunk=7)
    b = E.randomized(m, tr, (0.1, 0.0), 0.2, 7, 5, np.random.default_rng(3), var_floor=1e-6, chunk=7)
    for k in a:
        assert a[k].shape == (7, tr.k, 3)
        np.testing.assert_array_equal(a[k], b[k])
    # Realizations differ from each other (the estimates are random).
    assert np.ptp(a[E.MODEL_BASED][:, 0, 2]) > 1.0


def test_randomized_batches_change_speed_not_results():
    # The random stream is fixed by ``chunk``; fusing 2, 5 or all 11 realizations per engine call
    # (``batch``) gives the same posteriors as fusing each chunk on its own (batch = chunk).
    m = ring_models()
    tr = make_track(m)
    runs = [E.randomized(m, tr, (0.1, 0.0), 0.2, 11, 4, np.random.default_rng(3), var_floor=1e-6, chunk=3,
                         batch=b, attribution=True) for b in (3, 2, 5, None)]
    seen = []
    E.randomized(m, tr, (0.1, 0.0), 0.2, 11, 4, np.random.default_rng(3), var_floor=1e-6, chunk=3, batch=5,
                 progress=seen.append)
    assert seen == [6, 5]                                   # whole chunks per call, every realization once
    for other in runs[1:]:
        assert set(other) == set(runs[0])
        for k in runs[0]:
            np.testing.assert_allclose(other[k], runs[0][k], rtol=1e-12, atol=1e-12)
    # A different chunk is a different stream.
    c = E.randomized(m, tr, (0.1, 0.0), 0.2, 11, 4, np.random.default_rng(3), var_floor=1e-6, chunk=4)
    assert not np.allclose(c[E.MODEL_BASED], runs[0][E.MODEL_BASED])


def test_result_block_rows_and_summary():
    from pipeline.evaluation.metrics.results import cell_metrics, result_block
    m = ring_models()
    tr = make_track(m, truth=2)
    logs = E.randomized(m, tr, (0.0, 0.0), 0.1, 4, 3, np.random.default_rng(0), var_floor=1e-6)
    posts = {k: np.exp(v) for k, v in logs.items()}
    cols = result_block(logs, 2, experiment="randomized", setting="s", sigma_m=0.1)
    n = 3 * 4 * tr.k                              # With Uncertainty, Model Based, view-independent
    assert all(len(v) == n for v in cols.values())
    assert np.isfinite(cols["log10_mgr"]).all()  # log space: no inf even where P(truth) underflows
    i = 4 * tr.k + 5                              # second method, realization 0, step 5
    meth, r, k = cols["method"][i], cols["realization"][i], cols["step"][i]
    assert (meth, r, k) == (list(logs)[1], 0, 5) and cols["experiment"][i] == "randomized"
    p = posts[meth][r, k]
    np.testing.assert_allclose(cols["posterior"][i], p)
    assert cols["p_truth"][i] == pytest.approx(p[2])
    assert cols["log10_mgr"][i] == pytest.approx(np.log10(p.max() / p[2]))
    assert cols["correct"][i] == (p.argmax() == 2)
    s = E.summarize(logs, 2, PARAMS)
    for meth, v in s.items():
        corr = posts[meth].argmax(-1) == 2
        assert v["correct_final"] == pytest.approx(corr[:, -1].mean())
        assert v["correct_overall"] == pytest.approx(corr.mean())
        lm = logs[meth].max(-1) - logs[meth][..., 2]
        assert v["mgr95_final"] == pytest.approx(np.exp(np.percentile(lm[:, -1], 95)))
        assert v["mgr75_final"] >= 1.0
        assert v["log10_mgr95_final"] == pytest.approx(np.percentile(lm[:, -1], 95) / np.log(10))
        cm = cell_metrics(logs[meth], 2, PARAMS)
        assert cm["log10_mgr95_final"] == pytest.approx(v["log10_mgr95_final"])
        assert cm["correct_final"] == v["correct_final"]


def test_simple_bayes_uses_own_scores_and_repeats_over_realizations():
    from pipeline.method.fusion import simple_bayes
    m = ring_models()
    base = make_track(m, truth=1)
    rng = np.random.default_rng(5)
    own = rng.dirichlet(np.ones(3), size=(base.k, 4))               # (K, N_s, C)
    tr = E.TrackData(base.images, base.cam_xy, base.obj_xy, base.yaw, base.dropout, own)
    logs = E.randomized(m, tr, (0.0, 0.0), 0.2, 5, 3, np.random.default_rng(0), var_floor=1e-6)
    assert set(logs) == {E.WITH_UNCERTAINTY, E.MODEL_BASED, E.SIMPLE_BAYES,
                         "view_independent"}   # the Dirichlet runs per cell
    sb = logs[E.SIMPLE_BAYES]
    assert sb.shape == (5, tr.k, 3)
    np.testing.assert_allclose(sb[0], simple_bayes(own.mean(axis=1), return_log=True))
    np.testing.assert_array_equal(sb[0], sb[4])                      # pose noise does not touch it
    # Without own scores only the methods on the GP bank run.
    assert set(E.randomized(m, base, (0.0, 0.0), 0.2, 2, 3, np.random.default_rng(0), var_floor=1e-6)) == \
        {E.WITH_UNCERTAINTY, E.MODEL_BASED, "view_independent"}


def test_single_view_difficulty():
    m = ring_models()
    tr = make_track(m, truth=0)
    own = np.zeros((tr.k, 4, 3))
    own[:, :, 0] = 0.8
    own[:, :, 1:] = 0.1
    tr = E.TrackData(tr.images, tr.cam_xy, tr.obj_xy, tr.yaw, tr.dropout, own)
    d = E.single_view_first(m, tr, 0)
    assert d[E.SIMPLE_BAYES] == 1.0 and d["views"] == tr.k
    # Each GP view alone, at the true pose, with the truth's own mean response: mostly right.
    assert d[E.MODEL_BASED] >= 0.5 and d[E.WITH_UNCERTAINTY] >= 0.5
    # Against a wrong truth index the shares fall.
    w = E.single_view_first(m, tr, 2)
    assert w[E.MODEL_BASED] < d[E.MODEL_BASED] and w[E.SIMPLE_BAYES] == 0.0


def test_summary_keeps_an_overflowing_mgr_as_log10_and_stays_strict_json():
    import json
    C = 3
    logp = np.full((4, 2, C), -1e-300)
    logp[..., 0] = -5000.0                      # truth probability e^-5000: MGR overflows float64
    s = E.summarize({"model_based": logp}, 0, PARAMS)["model_based"]
    assert s["mgr95_final"] is None
    assert s["log10_mgr95_final"] == pytest.approx(5000 / np.log(10), rel=1e-12)
    json.dumps(s, allow_nan=False)              # no Infinity/NaN tokens in summary.json
    ok = E.summarize({"model_based": logp}, 1, PARAMS)["model_based"]   # truth among the likely ones
    assert ok["mgr95_final"] == pytest.approx(1.0) and ok["log10_mgr95_final"] == pytest.approx(0.0)


def test_bias_maps_zero_bias_matches_single_view():
    m = ring_models()
    tr = make_track(m)
    axis, post = E.bias_maps(m, tr, 0.4, 5)
    assert post.shape == (tr.k, 3, 5, 5)
    np.testing.assert_allclose(post.sum(1), 1.0)
    k = 2
    single = fuse_model_based(m, tr.inputs(tr.cam_xy[k:k + 1]), tr.measurement[k:k + 1], progress=False)[0]
    np.testing.assert_allclose(post[k, :, 2, 2], single, atol=1e-12)   # centre of the grid = no bias
    # [iy, ix] layout: bias (axis[ix], axis[iy])
    shifted = fuse_model_based(m, tr.inputs(tr.cam_xy[k:k + 1] + [axis[4], axis[0]]),
                               tr.measurement[k:k + 1], progress=False)[0]
    np.testing.assert_allclose(post[k, :, 0, 4], shifted, atol=1e-12)


def test_gp_rasters_match_marginal_predictions():
    m = ring_models()
    r = E.gp_rasters(m, grid_n=5, ring_n=8)
    assert r["raster_mean"].shape == (3, 2, 5, 5)
    g = r["grid"]
    mu, var = m.marginal(np.array([[g[3], g[1]]]))              # x = g[3], y = g[1] -> [iy=1, ix=3]
    np.testing.assert_allclose(r["raster_mean"][:, :, 1, 3], mu[0])
    np.testing.assert_allclose(r["raster_std"][:, :, 1, 3], np.sqrt(var[0]))
    assert r["train_y"].shape == (3, 2, 24)


def test_fusion_seconds_come_back_with_the_posteriors(monkeypatch):
    """Each fused method's wall time is returned with its posteriors (no clock to fill in): per
    engine call for one track, summed over the batches of a randomized setting; a pose-free
    posterior passed in as ``fixed`` is timed where it was fused, not again."""
    from itertools import count
    from types import SimpleNamespace

    from pipeline.method.names import WU_DROPOUT_ONLY, WU_POSES_ONLY

    m = ring_models()
    tr = make_track(m)
    ticks = count()
    monkeypatch.setattr(E, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks))))   # a call: 1 s
    one = E.biased(m, tr, (0.1, 0.0), 0.2, 4, np.random.default_rng(3), var_floor=1e-6, attribution=True)
    VI = "view_independent"
    assert one.seconds == {E.WITH_UNCERTAINTY: 1.0, E.MODEL_BASED: 1.0, WU_POSES_ONLY: 1.0, WU_DROPOUT_ONLY: 1.0,
                           VI: 1.0}
    many = E.randomized(m, tr, (0.1, 0.0), 0.2, 11, 4, np.random.default_rng(3), var_floor=1e-6, chunk=3, batch=5)
    assert many.seconds == {E.MODEL_BASED: 2.0, E.WITH_UNCERTAINTY: 2.0, VI: 2.0}   # two engine calls: 6 + 5
    assert set(many) >= set(many.seconds) and many[E.MODEL_BASED].shape[0] == 11

    own = np.full((tr.k, tr.dropout.shape[1], len(m.classes)), 1.0 / len(m.classes))
    with_own = E.TrackData(tr.images, tr.cam_xy, tr.obj_xy, tr.yaw, tr.dropout, own=own)
    fixed, _ = E.pose_free(E.track_input(m, with_own, var_floor=1e-6))
    assert fixed.seconds == {E.SIMPLE_BAYES: 1.0, VI: 1.0}
    again = E.biased(m, with_own, (0.0, 0.0), 0.2, 4, np.random.default_rng(3), var_floor=1e-6, fixed=fixed)
    assert E.SIMPLE_BAYES in again and E.SIMPLE_BAYES not in again.seconds
    assert E.add_seconds(fixed.seconds, again.seconds, many.seconds) == {
        E.SIMPLE_BAYES: 1.0, E.WITH_UNCERTAINTY: 3.0, E.MODEL_BASED: 3.0, VI: 3.0}
