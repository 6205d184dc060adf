"""Dirichlet class models: Minka's fixed point, the likelihood, the files (pipeline/method/dirichlet.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import optimize, stats
from scipy.special import digamma

from pipeline.method.dirichlet import (DirichletConvergenceWarning, DirichletFileError, DirichletModels,
                                       fit_class_dirichlets, fit_dirichlet, inv_digamma, log_likelihood, prepare)

THETA = np.array([2.0, 5.0, 0.5, 1.0])


@pytest.fixture(scope="module")
def draws():
    return np.random.default_rng(7).dirichlet(THETA, size=5000)


def test_inv_digamma_inverts_digamma_over_a_wide_range():
    y = np.linspace(-40.0, 12.0, 400)
    np.testing.assert_allclose(digamma(inv_digamma(y)), y, rtol=0, atol=1e-12)


def test_mle_recovers_known_theta_within_5_percent(draws):
    theta, diag = fit_dirichlet(draws, floor=1e-300)
    assert diag["converged"]
    np.testing.assert_array_less(np.abs(theta / THETA - 1.0), 0.05)


def test_mle_matches_an_independent_maximiser_of_the_log_likelihood(draws):
    theta, diag = fit_dirichlet(draws, floor=1e-300, tol=1e-13)
    mean_log = np.log(draws).mean(axis=0)

    def neg(z):  # over log θ, with scipy's own Dirichlet density (not our formula)
        return -stats.dirichlet.logpdf(draws.T, np.exp(z)).sum()

    res = optimize.minimize(neg, np.zeros(4), method="Nelder-Mead",
                            options={"xatol": 1e-11, "fatol": 1e-11, "maxiter": 40000, "maxfev": 80000})
    res = optimize.minimize(neg, res.x, method="BFGS", options={"gtol": 1e-9})
    best = np.exp(res.x)
    assert abs(diag["log_likelihood"] - (-res.fun)) <= 1e-6 * abs(res.fun)
    assert log_likelihood(theta, mean_log, len(draws)) >= -res.fun - 1e-6 * abs(res.fun)
    np.testing.assert_allclose(theta, best, rtol=1e-4)


def test_likelihood_equals_scipy_density_and_floor_is_applied():
    rng = np.random.default_rng(3)
    theta = rng.uniform(0.3, 4.0, size=(3, 5))
    m = DirichletModels(["a", "b", "c"], theta, floor=1e-6)
    g = rng.dirichlet(np.ones(5), size=(4, 2))
    want = np.stack([[stats.dirichlet.logpdf(prepare(x, 1e-6), t) for t in theta] for x in g.reshape(-1, 5)])
    np.testing.assert_allclose(m.log_likelihood(g).reshape(-1, 3), want, rtol=1e-12, atol=1e-10)
    z = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    assert np.all(np.isfinite(m.log_likelihood(z)))
    np.testing.assert_allclose(prepare(z, 1e-6).sum(), 1.0)
    assert prepare(z, 1e-6).min() >= 1e-6 / (1 + 4e-6)


def test_plain_and_accelerated_fixed_points_agree_and_nearly_alike_vectors_need_acceleration(draws):
    plain, dp = fit_dirichlet(draws, floor=1e-300, tol=1e-13, accelerate=False)
    fast, df = fit_dirichlet(draws, floor=1e-300, tol=1e-13)
    assert dp["converged"] and df["converged"] and df["iterations"] < dp["iterations"]
    np.testing.assert_allclose(fast, plain, rtol=1e-9)
    # An untrained network's outputs: all vectors close to one point, a precision in the thousands.
    alike = np.random.default_rng(1).dirichlet(np.linspace(50.0, 600.0, 12) * 10, size=12)
    with pytest.warns(DirichletConvergenceWarning):
        fit_dirichlet(alike, max_iter=2000, accelerate=False)
    theta, d = fit_dirichlet(alike, max_iter=2000)
    assert d["converged"] and d["iterations"] < 200 and d["precision"] > 1000
    # the likelihood's stationarity condition holds there: ψ(Σθ) - ψ(θ_j) + mean ln γ_j = 0
    grad = digamma(theta.sum()) - digamma(theta) + np.log(prepare(alike, 1e-6)).mean(axis=0)
    assert np.max(np.abs(grad)) < 1e-9


def test_non_convergence_warns_and_is_recorded(draws):
    with pytest.warns(DirichletConvergenceWarning, match="no convergence after 3"):
        _, diag = fit_dirichlet(draws, max_iter=3, accelerate=False)
    assert not diag["converged"] and diag["iterations"] == 3
    models, diags = fit_class_dirichlets({"x": draws, "y": draws[::-1]}, floor=1e-6, tol=1e-12, max_iter=2)
    assert [d["converged"] for d in diags] == [False, False] and all(d["warnings"] for d in diags)
    assert models.classes == ["x", "y"]


def test_subset_orders_classes_and_save_load_round_trip(tmp_path):
    m = DirichletModels(["a", "b", "c"], np.arange(1, 13, dtype=float).reshape(3, 4), floor=1e-5)
    sub = m.subset(["c", "a"])
    np.testing.assert_array_equal(sub.theta, m.theta[[2, 0]])
    with pytest.raises(KeyError, match="zz"):
        m.subset(["zz"])
    m.save(tmp_path, extra={"fit": {"passes": "deterministic"}})
    back = DirichletModels.load(tmp_path)
    np.testing.assert_array_equal(back.theta, m.theta)
    assert back.classes == m.classes and back.floor == m.floor and back.fingerprint() == m.fingerprint()
    index = json.loads((tmp_path / "index.json").read_text())
    assert index["fit"] == {"passes": "deterministic"} and index["fingerprint"] == m.fingerprint()
    # another parameter set has another fingerprint; a changed file is an error naming it
    assert DirichletModels(["a", "b", "c"], m.theta * 2, floor=1e-5).fingerprint() != m.fingerprint()
    DirichletModels(["a", "b", "c"], m.theta * 2, floor=1e-5).save(tmp_path / "other")
    (tmp_path / "theta.npz").write_bytes((tmp_path / "other" / "theta.npz").read_bytes())
    with pytest.raises(DirichletFileError, match="theta.npz: content differs"):
        DirichletModels.load(tmp_path)
    with pytest.raises(DirichletFileError, match="not found"):
        DirichletModels.load(tmp_path / "missing")


# -- the models stage ------------------------------------------------------------------------------
def test_models_stage_fits_saves_and_tracks_the_dirichlets(tmp_config):
    import dataclasses

    from pipeline.banks.model_bank import FeaturesError, training_views
    from pipeline.infra.config.own import with_own
    from pipeline.method.registry import providers
    from stages.framework.registry import STAGES
    from stages.framework.runner import read_manifest, run_stage, stage_key, stale_reason
    from tests.stages.test_models_stage import CLASSES, mcfg, write_features

    cfg = tmp_config({"models": {"classes": CLASSES, "n_components": 2, "restarts": 0},
                      "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]]}})
    feat = cfg.stage_dir("features")
    truth = write_features(feat / "bigbird.parquet")
    (feat / "manifest.json").write_text(json.dumps({"stage": "features", "key": "fake"}))
    run_stage(cfg, STAGES["models"], "k", {}, device="cpu", threads=1)
    folder = cfg.stage_dir("models") / "dirichlet"
    dm = DirichletModels.load(folder)
    assert dm.classes == sorted(CLASSES)
    for c, cls in enumerate(dm.classes):   # the camera-1 deterministic pass only (camera 3 is ignored)
        want, _ = fit_dirichlet(truth[cls][1].astype(np.float32), floor=cfg.models.dirichlet.floor,
                                tol=cfg.models.dirichlet.tol)
        np.testing.assert_allclose(dm.theta[c], want, rtol=1e-9)
    index = json.loads((folder / "index.json").read_text())
    assert index["fit"]["passes"] == "deterministic" and index["fits_not_converged"] == 0
    assert all(d["converged"] and d["n"] == 24 for d in index["diagnostics"])
    # Every Dirichlet file is a recorded output: changing one makes the stage stale, naming it.
    m = read_manifest(cfg, "models")
    assert {"dirichlet/index.json", "dirichlet/theta.npz"} <= set(m["outputs"])
    DirichletModels(dm.classes, dm.theta * 1.5, floor=dm.floor).save(folder)
    assert "models/dirichlet/" in stale_reason(cfg, "models", m["key"], m["parts"])
    # Its settings are part of the stage's key.
    other = tmp_config({"models": {"classes": CLASSES, "n_components": 2, "restarts": 0, "dirichlet": {"floor": 1e-5}},
                        "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]]}})
    assert stage_key(other, STAGES["models"], {"features": "x"})[0] != stage_key(cfg, STAGES["models"], {"features": "x"})[0]
    # passes = "both": the deterministic pass and every dropout pass of the ring (camera 1 only),
    # through the method's provider as the stage calls it
    def dirichlet_from_features(path, models_cfg, classes):
        return providers()["dirichlet"].fit(training_views(path, models_cfg.camera, classes),
                                            dataclasses.replace(cfg, models=models_cfg))

    import pyarrow.parquet as pq
    both, extra = dirichlet_from_features(feat / "bigbird.parquet",
                                          with_own(mcfg(), dirichlet=type(cfg.models.dirichlet)(passes="both")), CLASSES)
    t = pq.read_table(feat / "bigbird.parquet").to_pandas()
    for c, cls in enumerate(both.classes):
        rows = t[(t["object"] == cls) & (t["camera"] == 1)]
        want, _ = fit_dirichlet(np.stack(rows["scores"].to_numpy()), floor=1e-6, tol=1e-10)
        np.testing.assert_allclose(both.theta[c], want, rtol=1e-8)
    assert {d["n"] for d in extra["diagnostics"]} == {3 * 24} and extra["fit"]["passes"] == "both"
    assert not np.allclose(both.theta, dm.theta)
    with pytest.raises(FeaturesError, match="has none"):
        write_features(feat / "nodrop.parquet", dropout=False)
        dirichlet_from_features(feat / "nodrop.parquet", with_own(mcfg(), dirichlet=type(cfg.models.dirichlet)(passes="dropout")),
                                CLASSES)
