"""Weak hyperpriors (pipeline/method/gp_prior.py): the tails hold the stated mass, the MAP fit is
scikit-learn's fit with the prior added, it barely moves a well-determined fit, and it pulls a
fit that marginal likelihood alone pins at the length-scale bound back inside."""
import numpy as np
import pytest
from scipy import stats
from sklearn.gaussian_process import GaussianProcessRegressor

from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_prior import LogInverseGamma, input_range, inverse_gamma_for

THETA = np.deg2rad(np.arange(0, 360, 3))
X = np.c_[np.cos(THETA), np.sin(THETA)]
BOUNDS = dict(amplitude_bounds=(1e-6, 1e2), length_scale_bounds=(0.05, 10.0), noise_bounds=(1e-6, 1.0))


def fit(y, hyperprior, restarts=3):
    models, diags = fit_class_models([X], [np.asarray(y)[None]], ["a"], [0], restarts=restarts,
                                     hyperprior=hyperprior, progress=False, **BOUNDS)
    return models, diags[0]


@pytest.mark.parametrize("lo,hi", [(0.0524, 2.0), (1e-5, 0.1), (1.0, 1.5), (1e-3, 1e3)])
def test_inverse_gamma_puts_one_percent_below_lo_and_above_hi(lo, hi):
    a, b = inverse_gamma_for(lo, hi)
    assert stats.invgamma.cdf(lo, a, scale=b) == pytest.approx(0.01, abs=1e-9)
    assert stats.invgamma.sf(hi, a, scale=b) == pytest.approx(0.01, abs=1e-9)


def test_bad_prior_ranges_are_errors():
    for lo, hi in ((0.0, 1.0), (2.0, 1.0), (1.0, np.inf)):
        with pytest.raises(ValueError, match="0 < lo < hi"):
            inverse_gamma_for(lo, hi)
    with pytest.raises(ValueError, match="hyperprior must be"):
        fit(np.ones(len(X)), "gamma")


def test_log_density_and_slope_agree_with_scipy():
    prior = LogInverseGamma.between(0.05, 2.0)
    t = np.log(np.array([0.03, 0.2, 1.0, 5.0]))
    # log density of t = log x is log p_x(x) + t
    want = stats.invgamma.logpdf(np.exp(t), prior.alpha, scale=prior.beta) + t
    got = np.array([prior(v)[0] for v in t])
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-10, atol=1e-10)
    h = 1e-6
    for v in t:
        assert prior(v)[1] == pytest.approx((prior(v + h)[0] - prior(v - h)[0]) / (2 * h), rel=1e-6)


def test_input_range_is_the_view_spacing_and_the_diameter():
    lo, hi = input_range(X)
    assert lo == pytest.approx(2 * np.sin(np.deg2rad(1.5)), rel=1e-9)
    assert hi == pytest.approx(2.0, rel=1e-9)
    with pytest.raises(ValueError, match="same point"):
        input_range(np.zeros((3, 2)))


def test_a_well_determined_fit_barely_moves_and_predictions_are_scikit_learns():
    rng = np.random.default_rng(0)
    y = 0.3 + 0.25 * np.cos(THETA) + 0.002 * rng.standard_normal(len(THETA))
    idx = np.arange(60, 80)
    y[idx] += np.cumsum(rng.normal(0, 0.08, len(idx))) * np.hanning(len(idx))
    _, ml = fit(y, "none")
    models, mp = fit(y, "inverse_gamma")
    assert not ml["at_bound"] and not mp["at_bound"]
    for k in ("length_scale", "noise", "amplitude"):
        assert mp[k] == pytest.approx(ml[k], rel=0.05)
    assert mp["hyperprior"]["length_scale"]["lo"] == pytest.approx(input_range(X)[0])
    assert mp["log_prior"] is not None and ml["log_prior"] is None
    # The model bank predicts what scikit-learn predicts with the fitted kernel.
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    kernel = (ConstantKernel(mp["amplitude"], "fixed") * RBF(mp["length_scale"], "fixed")
              + WhiteKernel(mp["noise"], "fixed"))
    ref = GaussianProcessRegressor(kernel, alpha=0.0, optimizer=None).fit(X, y - mp["mean"])
    Xs = np.c_[np.cos(THETA[::7] + 0.01), np.sin(THETA[::7] + 0.01)]
    mu_ref, cov_ref = ref.predict(Xs, return_cov=True)
    mu, var = models.marginal(Xs)
    np.testing.assert_allclose(mu[:, 0, 0], mu_ref + mp["mean"], atol=1e-9)
    np.testing.assert_allclose(var[:, 0, 0], np.diag(cov_ref), atol=1e-9)
    # The reported marginal likelihood is the likelihood itself, not the prior-weighted objective.
    assert mp["log_marginal_likelihood"] == pytest.approx(float(ref.log_marginal_likelihood_value_), rel=1e-9)


def test_a_fit_pinned_at_the_length_scale_bound_comes_back_inside():
    # Two isolated spikes on a nearly flat ring: marginal likelihood alone drives the length
    # scale to the bound (below the views' spacing); the prior keeps it where the views resolve it.
    rng = np.random.default_rng(0)
    y = 0.01 + 0.005 * np.cos(THETA) + 0.0005 * rng.standard_normal(len(THETA))
    y[50] += 0.5
    y[80] += 0.4
    _, ml = fit(y, "none")
    _, mp = fit(y, "inverse_gamma")
    assert "length_scale at lower bound" in ml["at_bound"]
    assert "length_scale at lower bound" not in mp["at_bound"]
    assert mp["length_scale"] > input_range(X)[0]
    # MAP is the better of the two under its own objective (log likelihood + log prior).
    prior_ls, prior_n = (LogInverseGamma.between(*r) for r in (input_range(X), (1e-5, 0.1)))

    def log_post(d):
        return (d["log_marginal_likelihood"] + prior_ls(np.log(d["length_scale"]))[0]
                + prior_n(np.log(d["noise"]))[0])
    assert log_post(mp) >= log_post(ml) - 1e-6
