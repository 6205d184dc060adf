"""The paper's section 5.5 setting as a named experiment (``evaluate.biased_randomized``): a bias on
every pose, then Gaussian noise around the biased estimate, With Uncertainty told the same sigma."""
import dataclasses

import numpy as np
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.grid import population as P
from pipeline.infra.config import BiasedRandomizedConfig, ConfigError, EvaluateConfig, load_config
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models


def _setting(bias=(0.4, -0.25), sigma=0.3, realizations=400, n_x=30):
    ev = dataclasses.replace(EvaluateConfig(), experiments=("biased_randomized",),
                             biased_randomized=BiasedRandomizedConfig(bias_m=bias, sigma_m=sigma,
                                                                      realizations=realizations, n_loc_samples=n_x))
    (s,) = P.population_settings(ev)
    return s


def test_the_setting_carries_the_configured_bias_sigma_and_sizes():
    s = _setting()
    assert s.experiment == "biased_randomized"
    assert s.bias == (0.4, -0.25) and s.sigma == 0.3 and s.realizations == 400 and s.n_x == 30
    both = dataclasses.replace(EvaluateConfig(), experiments=("biased", "randomized", "biased_randomized"))
    kinds = [x.experiment for x in P.population_settings(both)]
    assert kinds.count("biased_randomized") == 1 and "biased" in kinds and "randomized" in kinds
    # the same sigma and bias as the biased experiment: still two settings (results are keyed by label)
    same = dataclasses.replace(both, biased_randomized=BiasedRandomizedConfig(
        bias_m=tuple(both.biased.bias_m), sigma_m=both.biased.sigma_m))
    labels = [x.label for x in P.population_settings(same)]
    assert len(set(labels)) == len(labels)
    # a randomized setting with the biased experiment's sigma and bias would merge with it: refused
    clash = dataclasses.replace(both, randomized=dataclasses.replace(
        both.randomized, bias_m=tuple(both.biased.bias_m), sigmas_m=(both.biased.sigma_m,)))
    with pytest.raises(ValueError, match="biased and randomized experiments both give the setting"):
        P.population_settings(clash)


def test_the_estimates_have_the_stated_bias_and_spread_and_the_method_is_told_sigma(monkeypatch):
    models = ring_models()
    track = make_track(models, K=5)
    s = _setting()
    seen = []

    def spy(models, track, estimates, samples, **kw):
        seen.append((estimates.copy(), samples.copy()))
        r, c = len(estimates), len(models.classes)
        return E.Posteriors({E.WITH_UNCERTAINTY: np.zeros((r, track.k, c)), E.MODEL_BASED: np.zeros((r, track.k, c))})

    monkeypatch.setattr(E, "fuse_track", spy)
    rng = np.random.default_rng(7)
    out = E.randomized(models, track, s.bias, s.sigma, s.realizations, s.n_x, rng, var_floor=1e-6)
    assert out[E.WITH_UNCERTAINTY].shape[0] == s.realizations
    est = np.concatenate([e for e, _ in seen])                       # (R, K, 2)
    smp = np.concatenate([x for _, x in seen])                       # (R, N_x, K, 2)
    err = (est - track.cam_xy[None]).reshape(-1, 2)                  # 2000 draws per axis
    se = s.sigma / np.sqrt(len(err))
    np.testing.assert_allclose(err.mean(axis=0), s.bias, atol=4 * se)          # the bias on every pose
    np.testing.assert_allclose(err.std(axis=0), [s.sigma] * 2, rtol=0.06)     # N(0, sigma) per axis around it
    assert abs(np.corrcoef(err.T)[0, 1]) < 0.1                                # the axes independent
    # The method's localization samples spread sigma around each (biased) estimate, not around the truth.
    around = (smp - est[:, None]).reshape(-1, 2)
    np.testing.assert_allclose(around.mean(axis=0), [0.0, 0.0], atol=4 * s.sigma / np.sqrt(len(around)))
    np.testing.assert_allclose(around.std(axis=0), [s.sigma] * 2, rtol=0.03)
    # Zero bias is the zero-mean randomized setting: the bias is what moves the mean.
    seen.clear()
    E.randomized(models, track, (0.0, 0.0), s.sigma, s.realizations, s.n_x, np.random.default_rng(7), var_floor=1e-6)
    zero = (np.concatenate([e for e, _ in seen]) - track.cam_xy[None]).reshape(-1, 2)
    np.testing.assert_allclose(err - zero, np.broadcast_to(s.bias, err.shape), atol=1e-12)


def test_the_config_section_is_checked(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[evaluate]\nexperiments = ["biased_randomized"]\n[evaluate.biased_randomized]\nbias_m = [0.1]\n')
    with pytest.raises(ConfigError, match="biased_randomized.bias_m"):
        load_config(cfg)
    cfg.write_text('[evaluate.biased_randomized]\nsigma_m = -1\n')
    with pytest.raises(ConfigError, match="sigma_m"):
        load_config(cfg)
