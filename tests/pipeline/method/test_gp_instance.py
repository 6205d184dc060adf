"""The instance term (pipeline/method/gp_instance.py): its joint predictive against a brute-force
joint Gaussian, the literal oracle with the term against the engines (numpy, torch on the CPU) to
1e-9, and a zero term equal to the plain models bit for bit."""
import numpy as np
import pytest

from pipeline.method.engine import predictive
from pipeline.method.fusion import engine_device, fuse_model_based, fuse_with_uncertainty
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_instance import InstanceGPClassModels
from tests.pipeline.method.test_fusion import random_case
from tests.support.literal_paper import gp_joint, literal_model_based, literal_uncertainty

TOL = 1e-9


def _k(A, B, a, ell):
    d = A[:, None, :] - B[None, :, :]
    return a * np.exp(-(d * d).sum(-1) / (2 * ell * ell))


def instance_case(seed, C=3, F=2, K=5, Nx=3, S=4, n_inst=(4, 3, 1), unit_circle=True):
    """Models whose classes have several training instances (a class of one gets b = 0)."""
    rng = np.random.default_rng(seed)
    X, Y, labels = [], [], []
    for c in range(C):
        n_i = n_inst[c % len(n_inst)]
        th = np.concatenate([np.sort(rng.uniform(0, 2 * np.pi, 6 + c)) for _ in range(n_i)])
        lab = np.repeat(np.arange(n_i), 6 + c)
        x = np.c_[np.cos(th), np.sin(th)] * (1.0 if unit_circle else rng.uniform(0.5, 2.0, (len(th), 1)))
        offsets = 0.05 * rng.standard_normal((n_i, F))
        X.append(x)
        Y.append(np.stack([0.25 + 0.1 * np.sin((f + 1) * th + 2.0 * c) + offsets[lab, f]
                           + 0.01 * rng.standard_normal(len(th)) for f in range(F)]))
        labels.append(lab)
    b = rng.uniform(0.001, 0.01, (C, F)) * np.array([[n_inst[c % len(n_inst)] > 1] for c in range(C)])
    models = InstanceGPClassModels([f"k{c}" for c in range(C)], list(range(F)), X, Y,
                                   np.array([[y.mean() for y in Yc] for Yc in Y]),
                                   rng.uniform(0.003, 0.03, (C, F)), rng.uniform(0.4, 1.5, (C, F)),
                                   rng.uniform(5e-4, 3e-3, (C, F)), instances=labels, instance_amplitude=b,
                                   instance_length_scale=rng.uniform(0.5, 4.0, (C, F)))
    _, samples, dropout = random_case(seed, C=C, F=F, K=K, Nx=Nx, S=S, unit_circle=unit_circle)
    return models, samples, dropout


def lit(models):
    return (models.X, models.Y, models.mean, models.amplitude, models.length_scale, models.noise)


def inst(models):
    return (models.instances, models.instance_amplitude, models.instance_length_scale)


def brute_joint(models, c, f, X):
    """The unseen instance as one more label in the generative model's covariance over training and
    test views together, then the Gaussian conditional of the test block on the training block."""
    XT, lab = models.X[c], models.instances[c]
    A = np.concatenate([XT, X])
    labs = np.concatenate([lab, np.full(len(X), lab.max() + 1)])
    b, lam = models.instance_amplitude[c, f], models.instance_length_scale[c, f]
    full = (_k(A, A, models.amplitude[c, f], models.length_scale[c, f])
            + (labs[:, None] == labs[None, :]) * _k(A, A, b, lam) + models.noise[c, f] * np.eye(len(A)))
    n = len(XT)
    Stt, Sxt, Sxx = full[:n, :n], full[n:, :n], full[n:, n:]
    G = np.linalg.solve(Stt, Sxt.T).T
    return models.mean[c, f] + G @ (models.Y[c][f] - models.mean[c, f]), Sxx - G @ Sxt.T


@pytest.mark.parametrize("seed,unit_circle", [(1, True), (2, False)])
def test_joint_predictive_equals_the_brute_force_joint_gaussian(seed, unit_circle):
    models, samples, _ = instance_case(seed, unit_circle=unit_circle)
    mu_p, cov_p = models.predict(samples)
    mu_e, cov_e = predictive(models, samples)
    for c in range(models.n_classes):
        for f in range(models.n_components):
            for x in range(len(samples)):
                mu_b, cov_b = brute_joint(models, c, f, samples[x])
                mu_l, cov_l = gp_joint(models.X[c], models.Y[c][f], models.mean[c, f], models.amplitude[c, f],
                                       models.length_scale[c, f], models.noise[c, f], samples[x],
                                       (models.instances[c], models.instance_amplitude[c, f],
                                        models.instance_length_scale[c, f]))
                for mu, cov in ((mu_l, cov_l), (mu_p[x, c, f], cov_p[x, c, f]), (mu_e[x, c, f], cov_e[x, c, f])):
                    np.testing.assert_allclose(mu, mu_b, rtol=0, atol=TOL)
                    np.testing.assert_allclose(cov, cov_b, rtol=0, atol=TOL)
    # The term is there: a view pair's covariance exceeds the plain model's by about b.
    assert np.any(models.instance_amplitude > 0)


def test_model_based_equals_the_brute_force_joint_density():
    """Model Based's posterior after k steps ∝ prior × Π_f N(z_{0..k}; μ, Σ): one joint Gaussian."""
    from scipy.stats import multivariate_normal

    models, samples, dropout = instance_case(3)
    track, meas = samples[0], dropout.mean(axis=1)
    got = fuse_model_based(models, track, meas, return_log=True, progress=False)
    K = len(track)
    for k in range(K):
        logp = np.zeros(models.n_classes)
        for c in range(models.n_classes):
            for f in range(models.n_components):
                mu, cov = brute_joint(models, c, f, track[:k + 1])
                logp[c] += multivariate_normal(mu, cov).logpdf(meas[:k + 1, f])
        logp -= np.logaddexp.reduce(logp)
        np.testing.assert_allclose(got[k], logp, rtol=0, atol=TOL)
    np.testing.assert_allclose(np.exp(got), literal_model_based(*lit(models), track, meas, inst=inst(models)),
                               rtol=0, atol=TOL)


@pytest.mark.parametrize("device", ["cpu", "torch-cpu"])
@pytest.mark.parametrize("seed,unit_circle,prior", [(4, True, None), (5, False, [0.5, 0.3, 0.2])])
def test_engines_match_the_literal_oracle_with_the_instance_term(device, seed, unit_circle, prior):
    if device == "torch-cpu":
        pytest.importorskip("torch")
    models, samples, dropout = instance_case(seed, unit_circle=unit_circle)
    with engine_device(device):
        wu = fuse_with_uncertainty(models, samples, dropout, prior=prior, progress=False)
        mb = fuse_model_based(models, samples[0], dropout.mean(axis=1), prior=prior, progress=False)
    np.testing.assert_allclose(wu, literal_uncertainty(*lit(models), samples, dropout, prior=prior, inst=inst(models)),
                               rtol=0, atol=TOL)
    np.testing.assert_allclose(mb, literal_model_based(*lit(models), samples[0], dropout.mean(axis=1), prior=prior,
                                                       inst=inst(models)), rtol=0, atol=TOL)
    # ...and the term changes the answer: the plain models' posterior differs.
    plain = GPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                          models.length_scale, models.noise)
    assert np.max(np.abs(fuse_with_uncertainty(plain, samples, dropout, prior=prior, progress=False) - wu)) > 1e-6


def test_zero_instance_term_is_the_plain_model_bit_for_bit():
    models, samples, dropout = instance_case(6, n_inst=(1,))
    assert not np.any(models.instance_amplitude)
    plain = GPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                          models.length_scale, models.noise)
    a = fuse_with_uncertainty(models, samples, dropout, return_log=True, progress=False)
    b = fuse_with_uncertainty(plain, samples, dropout, return_log=True, progress=False)
    assert np.array_equal(a, b)
    assert np.array_equal(fuse_model_based(models, samples[0], dropout.mean(1), return_log=True, progress=False),
                          fuse_model_based(plain, samples[0], dropout.mean(1), return_log=True, progress=False))


def test_factors_are_each_joint_covariance_factorised_once():
    """Every GP's training factor is the Cholesky of its covariance with the instance term (where it
    has one, the plain one where not) to 1e-12, and alpha solves it; the plain bank's are untouched."""
    models, _, _ = instance_case(8)
    plain = GPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                          models.length_scale, models.noise)
    for c, (fc, fp) in enumerate(zip(models.factors(), plain.factors())):
        T, lab = fc.T, models.instances[c]
        for f in range(models.n_components):
            K = (_k(T, T, models.amplitude[c, f], models.length_scale[c, f])
                 + (lab[:, None] == lab[None, :]) * _k(T, T, models.instance_amplitude[c, f],
                                                       models.instance_length_scale[c, f])
                 + models.noise[c, f] * np.eye(len(T)))
            np.testing.assert_allclose(fc.L[f], np.linalg.cholesky(K), rtol=0, atol=1e-12)
            np.testing.assert_allclose(K @ fc.alpha[f], models.Y[c][f] - models.mean[c, f], rtol=0, atol=1e-12)
            assert np.array_equal(fc.L[f], fp.L[f]) == (not models.has_instance(c, f))


def test_subset_keeps_the_instance_term_and_bad_labels_raise():
    models, _, _ = instance_case(7)
    sub = models.subset(["k1", "k0"], [1])
    assert isinstance(sub, InstanceGPClassModels)
    assert sub.instance_amplitude[0, 0] == models.instance_amplitude[1, 1]
    assert np.array_equal(sub.instances[1], models.instances[0])
    assert isinstance(models.with_test_variance(1e-3), InstanceGPClassModels)
    assert models.digest() != GPClassModels(models.classes, models.components, models.X, models.Y, models.mean,
                                            models.amplitude, models.length_scale, models.noise).digest()
    with pytest.raises(ValueError, match="instance labels"):
        InstanceGPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                              models.length_scale, models.noise, instances=[m[:-1] for m in models.instances],
                              instance_amplitude=models.instance_amplitude,
                              instance_length_scale=models.instance_length_scale)


def test_bank_files_keep_the_instance_term(tmp_path):
    import shutil

    from pipeline.method.gp import ModelFileError
    from pipeline.method.gp_files import load_bank, save_bank

    models, samples, dropout = instance_case(8)
    save_bank(models, tmp_path / "bank")
    back = load_bank(tmp_path / "bank")
    assert isinstance(back, InstanceGPClassModels) and back.digest() == models.digest()
    assert np.array_equal(fuse_with_uncertainty(back, samples, dropout, progress=False),
                          fuse_with_uncertainty(models, samples, dropout, progress=False))
    plain = GPClassModels(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                          models.length_scale, models.noise)
    save_bank(plain, tmp_path / "plain")
    assert type(load_bank(tmp_path / "plain")) is GPClassModels
    # A bank whose class files disagree (one plain file copied in, its digest updated) is refused.
    import json
    from pipeline.infra.cache import sha256_file

    shutil.copy(tmp_path / "plain" / "k1.npz", tmp_path / "bank" / "k1.npz")
    idx = json.loads((tmp_path / "bank" / "index.json").read_text())
    idx["sha256"]["k1.npz"] = sha256_file(tmp_path / "bank" / "k1.npz")
    (tmp_path / "bank" / "index.json").write_text(json.dumps(idx))
    with pytest.raises(ModelFileError, match="k1.npz.*in every class file"):
        load_bank(tmp_path / "bank")
