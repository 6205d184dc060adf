"""The heavy-tailed variants (``with_uncertainty_t``, ``model_based_t``): the engine (numba kernels
and torch) equal to the literal t oracle (tests/support/literal_student_t.py) to 1e-9; the methods
read ν from the bank and apply only where it is fitted; the ν fit and the Gaussian-scale reading."""
import math

import numpy as np
import pytest
from scipy.special import stdtr

from pipeline.method import student_t as T
from pipeline.method.fusion import engine_device, fuse_model_based, fuse_with_uncertainty
from pipeline.method.method_base import TrackInput
from pipeline.method.methods.student_t import ModelBasedT, WithUncertaintyT
from pipeline.method.names import MB_T, WU_T
from tests.pipeline.method.test_engine import assert_log_close, random_models, random_tracks
from tests.pipeline.method.test_fusion import literal_args, random_case
from tests.support.literal_student_t import literal_model_based_t, literal_uncertainty_t

TOL = 1e-9


@pytest.mark.parametrize("nu", [1.5, 4.0, 40.0])
def test_engine_equals_the_literal_t(nu):
    models, samples, dropout = random_case(7, K=4, Nx=2, S=3)
    dropout = dropout + np.random.default_rng(1).standard_normal(dropout.shape) * 0.05  # some far samples
    wu = fuse_with_uncertainty(models, samples, dropout, progress=False, nu=nu)
    assert np.allclose(wu, literal_uncertainty_t(*literal_args(models), samples, dropout, nu), rtol=0, atol=TOL)
    est, meas = samples[0], dropout.mean(axis=1)
    mb = fuse_model_based(models, est, meas, progress=False, nu=nu)
    assert np.allclose(mb, literal_model_based_t(*literal_args(models), est, meas, nu), rtol=0, atol=TOL)


def test_t_differs_from_the_gaussian_and_tends_to_it():
    models, samples, dropout = random_case(8, K=4, Nx=2, S=3)
    g = fuse_with_uncertainty(models, samples, dropout, progress=False, return_log=True)
    assert not np.allclose(fuse_with_uncertainty(models, samples, dropout, progress=False, return_log=True, nu=2.0),
                           g, atol=1e-3)
    # log t_ν - log N = O(z⁴/ν): at ν = 1e9 a difference far below the test's 1e-6
    near = fuse_with_uncertainty(models, samples, dropout, progress=False, return_log=True, nu=1e9)
    assert np.allclose(near, g, rtol=0, atol=1e-6)


@pytest.mark.parametrize("nu", [None, 0.0, -1.0, math.inf, "3"])
def test_bad_nu_is_refused(nu):
    models, samples, dropout = random_case(9, K=2, Nx=1, S=2)
    if nu is None:
        fuse_model_based(models, samples[0], dropout.mean(1), progress=False, nu=nu)
        return
    with pytest.raises(ValueError, match="nu"):
        fuse_model_based(models, samples[0], dropout.mean(1), progress=False, nu=nu)


def test_torch_equals_numpy_with_t():
    pytest.importorskip("torch")
    rng = np.random.default_rng(201)
    models = random_models(rng, 3, 2, ell=(0.3, 1.2))
    X, Z = random_tracks(rng, 3, 6, 5, 4, 2)
    out = []
    for dev in ("cpu", "torch-cpu"):
        with engine_device(dev):
            out.append((fuse_with_uncertainty(models, X, Z, return_log=True, progress=False, nu=3.0),
                        fuse_model_based(models, X[:, 0], Z.mean(2), return_log=True, progress=False, nu=3.0)))
    assert_log_close(out[1][0], out[0][0])
    assert_log_close(out[1][1], out[0][1])


def test_methods_read_nu_from_the_bank_and_apply_only_with_it():
    models, samples, dropout = random_case(10, K=3, Nx=2, S=3)
    est = samples[0]
    unit = lambda p: p / np.linalg.norm(p, axis=-1, keepdims=True)  # noqa: E731
    base = dict(dropout=dropout, estimates=est[None], samples=samples[None], inputs=unit)
    assert not WithUncertaintyT().applies(TrackInput(gp=models, **base))
    tailed = models.with_tail_df({WU_T: 3.0, MB_T: 5.0})
    assert tailed.subset(tailed.classes[:2], tailed.components).tail_df == {WU_T: 3.0, MB_T: 5.0}
    t = TrackInput(gp=tailed, **base)
    assert WithUncertaintyT().applies(t) and ModelBasedT().applies(t)
    # t.inputs normalises the (unit) samples once more: equal to rounding, not bit for bit
    assert np.allclose(WithUncertaintyT().fuse(t)[0],
                       fuse_with_uncertainty(models, samples, dropout, return_log=True, progress=False, nu=3.0),
                       rtol=0, atol=TOL)
    assert np.allclose(ModelBasedT().fuse(t)[0],
                       fuse_model_based(models, est, dropout.mean(1), return_log=True, progress=False, nu=5.0),
                       rtol=0, atol=TOL)
    with pytest.raises(ValueError, match="degrees of freedom"):
        models.with_tail_df({WU_T: 0.0})


def test_fit_df_recovers_nu_and_calls_gaussians_light():
    rng = np.random.default_rng(0)
    n = 20000
    # ML ν̂ of t_4 from n draws has a standard deviation near 0.15 (Fisher information): 4 sd
    assert abs(T.fit_df(rng.standard_t(4.0, n)) - 4.0) < 0.6
    assert T.fit_df(rng.standard_normal(n)) > 50
    assert T.fit_df([]) is None and T.fit_df([np.nan]) is None


def test_gaussian_equivalent_reads_a_t_as_its_pit():
    z = np.array([-40.0, -2.5, 0.0, 1.0, 3.0, 60.0])
    g = T.gaussian_equivalent(z, 3.0)
    from scipy.special import ndtr
    assert np.allclose(ndtr(g[1:-1]), stdtr(3.0, z[1:-1]), rtol=0, atol=1e-12)
    assert np.all(np.isfinite(g)) and np.all(np.diff(g) > 0) and g[2] == 0.0
    # the t's own 95 % interval is the Gaussian-scale ±1.96
    q = -T.gaussian_equivalent(np.array([-abs(float(__import__("scipy.stats").stats.t.ppf(0.025, 3.0)))]), 3.0)
    assert q[0] == pytest.approx(1.959963984540054, abs=1e-9)


def test_logpdf_is_the_density():
    from scipy.stats import t as student
    z = np.linspace(-30, 30, 13)
    for nu in (1.0, 2.5, 100.0):
        assert np.allclose(T.logpdf(z, nu), student.logpdf(z, nu), rtol=0, atol=1e-12)
