"""models.dirichlet.entries: Dirichlets on (chosen entries, rest mass), per candidate set."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import dirichlet as sp_dirichlet

from pipeline.method.dirichlet import reduced_sets
from pipeline.method.methods.dirichlet import DirichletFitConfig
from pipeline.method.dirichlet import DirichletModels, fit_dirichlet, reduce_vectors


def test_reduced_models_score_the_reduced_vector():
    theta = np.array([[2.0, 0.5, 1.5], [0.4, 4.0, 0.3]])
    m = DirichletModels(["a", "b"], theta, floor=1e-9, select=[4, 1], input_dim=6)
    assert m.dim == 6
    g = np.random.default_rng(0).dirichlet(np.ones(6), size=5)
    red = np.stack([g[:, 4], g[:, 1], 1 - g[:, 4] - g[:, 1]], axis=1)
    np.testing.assert_allclose(reduce_vectors(g, [4, 1]), red)
    got = m.log_likelihood(g)
    for c in range(2):
        np.testing.assert_allclose(got[:, c], sp_dirichlet.logpdf(red.T, theta[c]), rtol=1e-9)
    with pytest.raises(ValueError, match="vectors have 3 entries"):
        m.log_likelihood(red)


def test_sets_are_fitted_on_reduced_vectors_and_survive_save_and_load(tmp_path):
    rng = np.random.default_rng(1)
    vectors = {"a": rng.dirichlet([3.0, 1.0, 0.5, 0.5, 2.0, 1.0], size=4000),
               "b": rng.dirichlet([0.5, 3.0, 1.0, 2.0, 0.5, 1.0], size=4000)}
    plan = {"a": {"classes": ["a", "b"], "components": [0, 4, 1]}}
    dcfg = DirichletFitConfig(entries=2)
    sets, diags = reduced_sets(vectors, plan, dcfg, 6)
    m = sets["a"]
    assert m.classes == ["a", "b"] and m.select.tolist() == [0, 4] and m.theta.shape == (2, 3)
    # the aggregation property of the true law: Dir(3, 2, 1 + 0.5 + 0.5 + 1) for class a
    np.testing.assert_allclose(m.theta[0], [3.0, 2.0, 3.0], rtol=0.08)
    assert len(diags) == 2 and all(d["candidate_set"] == "a" for d in diags)
    whole = DirichletModels(["a", "b"], np.stack([fit_dirichlet(vectors[c])[0] for c in "ab"]), floor=1e-6, sets=sets)
    whole.save(tmp_path)
    back = DirichletModels.load(tmp_path)
    assert back.fingerprint() == whole.fingerprint()
    pick = back.for_set("a", ["b", "a"])
    assert pick.classes == ["b", "a"] and pick.select.tolist() == [0, 4]
    np.testing.assert_allclose(pick.theta, m.theta[::-1])
    assert back.for_set("other", ["a"]).theta.shape == (1, 6)   # no set: the whole vector
