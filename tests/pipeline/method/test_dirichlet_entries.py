"""models.dirichlet.entries: a whole-vector Dirichlet reduced to chosen entries plus the rest mass."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import dirichlet as sp_dirichlet

from pipeline.method.dirichlet import DirichletModels, fit_dirichlet


def test_aggregate_is_the_dirichlet_of_the_aggregated_vector():
    theta = np.array([[2.0, 0.5, 1.5, 0.2, 3.0, 0.8], [0.4, 4.0, 0.3, 1.0, 0.6, 2.0]])
    m = DirichletModels(["a", "b"], theta, floor=1e-9).aggregate([4, 1])
    assert m.dim == 6 and m.theta.shape == (2, 3)
    g = np.random.default_rng(0).dirichlet(theta[0], size=5)
    got = m.log_likelihood(g)
    red = np.stack([g[:, 4], g[:, 1], 1 - g[:, 4] - g[:, 1]], axis=1)
    for c in range(2):
        want = sp_dirichlet.logpdf(red.T, [theta[c, 4], theta[c, 1], theta[c, [0, 2, 3, 5]].sum()])
        np.testing.assert_allclose(got[:, c], want, rtol=1e-9)


def test_aggregation_property_holds_for_samples():
    """Samples of the whole Dir(θ), aggregated, fit back to the aggregated θ."""
    theta = np.array([3.0, 1.0, 0.5, 0.5, 2.0, 1.0])
    g = np.random.default_rng(1).dirichlet(theta, size=20000)
    m = DirichletModels(["a"], theta[None], floor=1e-9).aggregate([0, 4])
    fit, _ = fit_dirichlet(m.reduce(g), floor=1e-12)
    np.testing.assert_allclose(fit, m.theta[0], rtol=0.05)
    np.testing.assert_allclose(m.theta[0], [3.0, 2.0, 3.0])


def test_subset_keeps_the_reduction_and_bad_entries_fail():
    theta = np.ones((3, 5))
    m = DirichletModels(["a", "b", "c"], theta, floor=1e-6).aggregate([0, 2])
    s = m.subset(["c", "a"])
    assert s.classes == ["c", "a"] and s.dim == 5 and s.theta.shape == (2, 3)
    with pytest.raises(ValueError, match="distinct entries"):
        DirichletModels(["a"], theta[:1], floor=1e-6).aggregate([0, 0])
    with pytest.raises(ValueError, match="vectors have 3 entries"):
        s.log_likelihood(np.full((1, 3), 1 / 3))
