"""GP class models: joint predictive vs scikit-learn and the literal Eq. 13-16, fitting, files."""
import json
import warnings

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

from pipeline.method.gp import GPClassModels, ModelFileError
from pipeline.method.gp_files import save_bank, load_bank
from pipeline.method.gp_fit import fit_class_models
from tests.support.literal_paper import gp_joint


def ring(n, phase=0.0):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False) + phase
    return np.c_[np.cos(th), np.sin(th)]


def make_models(rng, C=3, F=2, unit_circle=True):
    """Random models, each class with its own training set (sizes differ)."""
    X, Y = [], []
    for c in range(C):
        n = 15 + 3 * c
        x = ring(n, rng.uniform(0, 1)) if unit_circle else rng.uniform(-2, 2, (n, 2))
        th = np.arctan2(x[:, 1], x[:, 0])
        Y.append(np.stack([0.2 + 0.1 * np.sin((f + 1) * th + c) + 0.01 * rng.standard_normal(n)
                           for f in range(F)]))
        X.append(x)
    mean = np.array([[y.mean() for y in Yc] for Yc in Y])
    return GPClassModels([f"class_{c}" for c in range(C)], list(range(10, 10 + F)), X, Y, mean,
                         rng.uniform(0.005, 0.05, (C, F)), rng.uniform(0.3, 1.5, (C, F)),
                         rng.uniform(5e-4, 3e-3, (C, F)))


def sklearn_predict(models, c, f, Xs):
    k = (ConstantKernel(models.amplitude[c, f]) * RBF(models.length_scale[c, f])
         + WhiteKernel(models.noise[c, f]))
    g = GaussianProcessRegressor(k, alpha=0.0, optimizer=None, normalize_y=False)
    g.fit(models.X[c], models.Y[c][f] - models.mean[c, f])
    mu, cov = g.predict(Xs, return_cov=True)
    return mu + models.mean[c, f], cov


@pytest.mark.parametrize("unit_circle", [True, False])
def test_joint_predictive_equals_sklearn_and_literal(unit_circle):
    rng = np.random.default_rng(1 if unit_circle else 2)
    models = make_models(rng, unit_circle=unit_circle)
    Xs = rng.standard_normal((2, 3, 5, 2))                      # (..., K, d) with two leading axes
    if unit_circle:
        Xs /= np.linalg.norm(Xs, axis=-1, keepdims=True)
    mu, cov = models.predict(Xs)
    assert mu.shape == (2, 3, 3, 2, 5) and cov.shape == (2, 3, 3, 2, 5, 5)
    for i in range(2):
        for j in range(3):
            for c in range(3):
                for f in range(2):
                    m_sk, c_sk = sklearn_predict(models, c, f, Xs[i, j])
                    np.testing.assert_allclose(mu[i, j, c, f], m_sk, rtol=0, atol=1e-9)
                    np.testing.assert_allclose(cov[i, j, c, f], c_sk, rtol=0, atol=1e-9)
                    m_l, c_l = gp_joint(models.X[c], models.Y[c][f], models.mean[c, f], models.amplitude[c, f],
                                        models.length_scale[c, f], models.noise[c, f], Xs[i, j])
                    np.testing.assert_allclose(mu[i, j, c, f], m_l, rtol=0, atol=1e-9)
                    np.testing.assert_allclose(cov[i, j, c, f], c_l, rtol=0, atol=1e-9)
    # The white noise is on the diagonal: the variance never drops below σ_n².
    var = np.diagonal(cov, axis1=-2, axis2=-1)
    assert np.all(var >= models.noise[None, None, :, :, None] * (1 - 1e-9))
    m, v = models.marginal(Xs)
    np.testing.assert_allclose(np.moveaxis(m, -3, -1), mu, atol=1e-12)
    np.testing.assert_allclose(np.moveaxis(v, -3, -1), var, atol=1e-12)


def test_plain_2d_far_from_origin_is_translation_invariant():
    rng = np.random.default_rng(3)
    models = make_models(rng, unit_circle=False)
    shift = np.array([40.0, -25.0])
    moved = GPClassModels(models.classes, models.components, [x + shift for x in models.X], models.Y,
                          models.mean, models.amplitude, models.length_scale, models.noise)
    Xs = rng.uniform(-2, 2, (4, 6, 2))
    mu0, cov0 = models.predict(Xs)
    mu1, cov1 = moved.predict(Xs + shift)
    np.testing.assert_allclose(mu1, mu0, atol=1e-10)
    np.testing.assert_allclose(cov1, cov0, atol=1e-10)


def test_fit_recovers_hyperparameters_and_is_deterministic():
    rng = np.random.default_rng(4)
    X = ring(90)
    true = dict(a=0.02, ell=0.6, sn2=1e-4)
    D2 = ((X[:, None] - X[None]) ** 2).sum(-1)
    K = true["a"] * np.exp(-D2 / (2 * true["ell"] ** 2)) + true["sn2"] * np.eye(90)
    Y = [0.3 + np.linalg.cholesky(K) @ rng.standard_normal((90, 2)) for _ in range(2)]
    Y = [y.T for y in Y]                                        # (F, N)
    m1, d1 = fit_class_models([X, X], Y, ["a", "b"], [3, 7], restarts=2, seed=5, progress=False)
    m2, _ = fit_class_models([X, X], Y, ["a", "b"], [3, 7], restarts=2, seed=5, progress=False)
    np.testing.assert_array_equal(m1.length_scale, m2.length_scale)
    np.testing.assert_array_equal(m1.amplitude, m2.amplitude)
    # Marginal likelihood recovers the generating length scale and noise within a modest factor.
    assert np.all(np.abs(np.log(m1.length_scale / true["ell"])) < np.log(2.0))
    assert np.all(np.abs(np.log(m1.noise / true["sn2"])) < np.log(3.0))
    np.testing.assert_allclose(m1.mean, [[y.mean() for y in Yc] for Yc in Y])
    assert len(d1) == 4 and {d["class"] for d in d1} == {"a", "b"}
    for d in d1:
        assert np.isfinite(d["log_marginal_likelihood"]) and d["n_train"] == 90
        assert d["at_bound"] == []
    # The reported log marginal likelihood is sklearn's for the fitted kernel on y - m.
    d = d1[0]
    k = ConstantKernel(d["amplitude"]) * RBF(d["length_scale"]) + WhiteKernel(d["noise"])
    g = GaussianProcessRegressor(k, alpha=0.0, optimizer=None).fit(X, Y[0][0] - d["mean"])
    assert abs(g.log_marginal_likelihood_value_ - d["log_marginal_likelihood"]) < 1e-6


def test_fit_reports_bound_warnings():
    rng = np.random.default_rng(6)
    X = ring(40)
    th = np.arctan2(X[:, 1], X[:, 0])
    Y = [np.stack([0.3 + 0.1 * np.sin(th) + 0.005 * rng.standard_normal(40)])]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing may leak out of the fit: all warnings are captured
        _, diags = fit_class_models([X], Y, ["a"], [0], restarts=1, length_scale_bounds=(0.05, 0.08),
                                    progress=False)
    d = diags[0]
    assert "length_scale at upper bound" in d["at_bound"]
    assert any("ConvergenceWarning" in w and "length_scale" in w for w in d["warnings"])


def test_save_load_roundtrip(tmp_path):
    rng = np.random.default_rng(7)
    models = make_models(rng)
    models.component_names = ["comp_a", "comp_b"]
    save_bank(models, tmp_path, extra={"rule": "top_mean"})
    index = json.loads((tmp_path / "index.json").read_text())
    assert index["classes"] == models.classes and index["rule"] == "top_mean"
    assert index["hyperparameters"]["class_1"]["11"]["length_scale"] == pytest.approx(models.length_scale[1, 1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["class_0.npz", "class_1.npz", "class_2.npz", "index.json"]
    loaded = load_bank(tmp_path)
    assert loaded.classes == models.classes and loaded.components == models.components
    assert loaded.component_names == ["comp_a", "comp_b"]
    Xs = ring(7)[None]
    for a, b in zip(loaded.predict(Xs), models.predict(Xs)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="reserved"):
        save_bank(models, tmp_path / "other", extra={"classes": []})


def test_load_errors_name_the_file(tmp_path):
    rng = np.random.default_rng(8)
    save_bank(make_models(rng), tmp_path)
    with pytest.raises(ModelFileError, match="index.json.*not found"):
        load_bank(tmp_path / "missing")
    (tmp_path / "class_1.npz").unlink()
    with pytest.raises(ModelFileError, match="class_1.npz.*not found"):
        load_bank(tmp_path)
    # An object array would need unpickling: refused, not executed.
    with open(tmp_path / "class_1.npz", "wb") as fh:
        np.savez(fh, X=np.array([object()], dtype=object))
    with pytest.raises(ModelFileError, match="class_1.npz"):
        load_bank(tmp_path)
    (tmp_path / "index.json").write_text("{not json")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        load_bank(tmp_path)
    (tmp_path / "index.json").write_bytes(b'{"format": "\xff\xfe"}')     # not UTF-8
    with pytest.raises(ModelFileError, match=r"index\.json: not valid JSON"):
        load_bank(tmp_path)
    for bad, msg in (('"classes": "k0", "components": [0], "files": {}', "'classes' must be a non-empty list"),
                     ('"classes": ["k0"], "components": [0.5], "files": {}', "'components' must be a non-empty list"),
                     ('"classes": ["k0"], "components": [0], "files": ["a.npz"]', "'files' must be an object")):
        (tmp_path / "index.json").write_text('{"format": "viewfuse.gp_class_models", "version": 1, ' + bad + "}")
        with pytest.raises(ModelFileError, match=msg):
            load_bank(tmp_path)
    (tmp_path / "index.json").write_text('{"format": "viewfuse.gp_class_models", "version": 99}')
    with pytest.raises(ModelFileError, match="unsupported model index version 99"):
        load_bank(tmp_path)


def test_invalid_models_and_inputs_raise():
    X = [ring(10)]
    Y = [np.zeros((1, 10))]
    one = np.ones((1, 1))
    with pytest.raises(ValueError, match="length_scale"):
        GPClassModels(["a"], [0], X, Y, one, one, -one, one)
    with pytest.raises(ValueError, match="targets must be"):
        GPClassModels(["a"], [0], X, [np.zeros((2, 10))], one, one, one, one)
    m = GPClassModels(["a"], [0], X, Y, one, one, one, one)
    with pytest.raises(ValueError, match="NaN"):
        m.predict(np.full((3, 2), np.nan))
    with pytest.raises(KeyError, match="not modelled"):
        m.select(["b"])
    with pytest.raises(ValueError, match="amplitude_bounds"):
        fit_class_models(X, Y, ["a"], [0], amplitude_bounds=(1.0, 0.5), progress=False)


def test_one_content_hash_per_gp_and_bank(tmp_path):
    """The digest follows the content, not the names or the object: a saved and reloaded bank has
    the same one; another target or hyperparameter, or (unless trained_only) a test-domain
    variance, changes it."""
    m = make_models(np.random.default_rng(4))
    save_bank(m, tmp_path)
    back = load_bank(tmp_path)
    assert back.digest() == m.digest() and back.digest(1, 0) == m.digest(1, 0)
    assert m.digest(1, 0) != m.digest(1, 1) != m.digest()
    other = make_models(np.random.default_rng(4))
    other.Y[1][0, 0] += 1e-9
    assert other.digest(1, 0) != m.digest(1, 0) and other.digest(0, 0) == m.digest(0, 0)
    assert other.digest() != m.digest()
    cal = m.with_test_variance(0.01)
    assert cal.digest() != m.digest() and cal.digest(0, 1, trained_only=True) == m.digest(0, 1, trained_only=True)
