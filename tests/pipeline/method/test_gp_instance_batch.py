"""Every instance-term fit at once (pipeline/method/gp_instance_batch.py): its stacked objective
equals the per-fit JointObjective (balanced and dense evaluations, with and without priors, the
instance term's split and λ priors among them), and
over many random generated hierarchical fits its optimum is at least the per-fit route's (LML + log
prior within 1e-6 or higher), with every fit's record kept."""
import numpy as np
import pytest

from pipeline.method.gp_batch import prior_rows
from pipeline.method.gp_instance_batch import FAILED, InstanceProblem, InstanceStack, balanced_order, \
    instance_prior_rows
from pipeline.method.gp_instance_fit import JointObjective, fit_instance_models
from pipeline.method.gp_prior import LogInverseGamma, LogitBeta, input_range


def hierarchical_class(rng, n_inst, n_views, F, balanced=True):
    """A class of n_inst turntable instances (the same azimuths, or each its own when not balanced)
    drawn from m + g(θ) + h_i(θ) + ε with random hyperparameters, F components."""
    base = np.sort(rng.uniform(0, 2 * np.pi, n_views))
    rings = [base if balanced else np.sort(rng.uniform(0, 2 * np.pi, n_views + int(rng.integers(0, 3))))
             for _ in range(n_inst)]
    th = np.concatenate(rings)
    lab = np.repeat(np.arange(n_inst), [len(r) for r in rings])
    X = np.c_[np.cos(th), np.sin(th)]
    D2 = ((X[:, None] - X[None]) ** 2).sum(-1)
    same = lab[:, None] == lab[None]
    Y = []
    for _ in range(F):
        a, ell, b, lam = 10 ** rng.uniform(-3, -1), rng.uniform(0.3, 2.0), 10 ** rng.uniform(-4, -1.5), rng.uniform(0.3, 5)
        K = a * np.exp(-D2 / (2 * ell ** 2)) + same * b * np.exp(-D2 / (2 * lam ** 2)) + 10 ** rng.uniform(-4, -2) * np.eye(len(X))
        Y.append(rng.uniform(0, 0.5) + np.linalg.cholesky(K) @ rng.standard_normal(len(X)))
    perm = rng.permutation(len(X))   # views in any order: the balanced reduction must find them
    return X[perm], np.stack(Y)[:, perm], lab[perm]


@pytest.mark.parametrize("balanced", [True, False])
@pytest.mark.parametrize("with_prior", [True, False, "split"])
def test_stacked_objective_equals_the_per_fit_objective(balanced, with_prior):
    rng = np.random.default_rng(3 + balanced + 2 * (with_prior is True) + 4 * (with_prior == "split"))
    X, Y, lab = hierarchical_class(rng, 4, 6, 1, balanced)
    y = Y[0] - Y[0].mean()
    priors = {1: LogInverseGamma.between(*input_range(X)), 2: LogInverseGamma.between(1e-5, 0.1)} if with_prior else {}
    split = LogitBeta(2.0, 3.0) if with_prior == "split" else None
    inst = np.full((2, 2), np.nan)
    if split is not None:
        priors[4] = priors[1]
        inst = instance_prior_rows(split, priors[4])
    obj = JointObjective(X, y, lab, priors, split)
    T = np.log([[0.02, 0.7, 1e-3, 0.01, 3.0], [0.1, 0.3, 1e-2, 0.05, 0.5], [1e-3, 2.0, 1e-4, 1e-3, 0.1]])
    rows = prior_rows({i: p for i, p in priors.items() if i in (1, 2)}, 1, 2)
    stack = InstanceStack([InstanceProblem(X, y, lab, np.zeros((5, 2)), rows, T, inst)])
    assert (stack.structures[0].order is not None) == balanced
    lml, lp, grad = stack.evaluate(np.zeros(len(T), int), T)
    for k, t in enumerate(T):
        f, g = obj(t)
        assert lml[k] + lp[k] == pytest.approx(-f, rel=1e-11, abs=1e-9)
        np.testing.assert_allclose(grad[k], -g, rtol=1e-9, atol=1e-9)
    three = InstanceStack([InstanceProblem(X, y, lab, np.zeros((5, 2)), rows, T, inst)] * len(T))
    both = [(s, obj.laplace_sd(t)) for s, t in zip(three.laplace_sd(T), T)]
    assert all((s is None) == (r is None) for s, r in both)
    for s, r in both:
        if s is not None:
            np.testing.assert_allclose(s, r, rtol=1e-6)


def test_balanced_order_needs_the_same_inputs_in_every_instance():
    X = np.c_[np.arange(6.0) % 3, np.zeros(6)]
    lab = np.array([0, 0, 0, 1, 1, 1])
    order = balanced_order(X[::-1], lab[::-1])
    assert order.shape == (2, 3)
    assert np.array_equal(X[::-1][order[0]], X[::-1][order[1]])
    X2 = X.copy()
    X2[4, 0] = 7.0
    assert balanced_order(X2, lab) is None
    assert balanced_order(X[:5], lab[:5]) is None


def test_a_covariance_that_is_not_positive_definite_scores_as_the_per_fit_objective():
    # Exactly singular, not nearly: whether a nearly singular K (near-equal inputs) factorises
    # depends on the last bit of each route's rounding, which differs between processors (66.2
    # on an AMD EPYC). Here every input is equal (D² = 0), a = e⁰ = 1, the instance term
    # b = e⁻¹⁰⁰⁰ underflows to 0 and σ² = 1e-300 vanishes beside 1: K (and the balanced route's
    # P = m·A + Q) is a constant matrix of small integers, its second Cholesky pivot 1 − 1·1 = 0
    # exactly in any order of operations, so every route fails on every processor.
    X, lab, y = np.tile([1.0, 0.0], (8, 1)), np.repeat([0, 1], 4), np.ones(8)
    t = np.array([[0.0, np.log(10.0), np.log(1e-300), -1000.0, np.log(10.0)]])
    assert JointObjective(X, y, lab, {})(t[0])[0] == 1e300
    for labels in (lab, np.r_[lab[:-1], 2]):   # balanced, dense
        stack = InstanceStack([InstanceProblem(X, y, labels, np.zeros((5, 2)), np.full((2, 2), np.nan), t)])
        lml, lp, grad = stack.evaluate(np.zeros(1, int), t)
        assert lml[0] == FAILED and lp[0] == 0.0 and not grad.any()


def test_the_batched_optimum_is_at_least_the_per_fit_one_on_random_fits():
    """Eight generated banks (classes of 2-4 instances, balanced and not, one class of a single
    instance, with and without hyperpriors, half with the instance prior "split"): 96 joint fits,
    each batched optimum within 1e-6 of
    the per-fit one or higher, and the records of both routes carry the same fields."""
    worst, n = np.inf, 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        Xs, Ys, labs = [], [], []
        for c in range(4):
            X, Y, lab = hierarchical_class(rng, int(rng.integers(2, 5)), int(rng.integers(4, 9)), 3, balanced=c % 2 == 0)
            Xs.append(X), Ys.append(Y), labs.append(lab)
        X, Y, _ = hierarchical_class(rng, 1, 7, 3)
        Xs.append(X), Ys.append(Y), labs.append(np.zeros(len(X), int))
        kw = dict(classes=[f"c{i}" for i in range(5)], components=[0, 1, 2], restarts=2, seed=seed,
                  hyperprior="inverse_gamma" if seed % 2 else "none", progress=False,
                  instance_prior="split" if seed % 4 >= 2 else "none", split_prior=(1.5, 2.5))
        _, batch = fit_instance_models(Xs, Ys, labs, instance_route="batch", **kw)
        _, each = fit_instance_models(Xs, Ys, labs, instance_route="per_fit", **kw)
        for b, e in zip(batch, each):
            assert set(b) == set(e) and b["instance_term"] == e["instance_term"]
            if not b["instance_term"]:
                assert b == e
                continue
            n += 1
            assert b["instance_optimizer"]["route"] == "batch" and len(b["instance_optimizer"]["runs"]) == 4
            assert (b["instance_prior"] is not None) == (seed % 4 >= 2) and b["instance_prior"] == e["instance_prior"]
            obj_b = b["log_marginal_likelihood"] + (b["log_prior"] or 0.0)
            obj_e = e["log_marginal_likelihood"] + (e["log_prior"] or 0.0)
            worst = min(worst, obj_b - obj_e)
    assert n == 8 * 4 * 3 and worst >= -1e-6, (n, worst)


def test_an_unknown_instance_prior_or_bad_split_shapes_are_errors():
    X = np.c_[np.cos(np.arange(4.0)), np.sin(np.arange(4.0))]
    args = ([X], [np.arange(4.0)[None]], [np.array([0, 0, 1, 1])], ["c"], [0])
    with pytest.raises(ValueError, match="instance_prior"):
        fit_instance_models(*args, instance_prior="beta", progress=False)
    with pytest.raises(ValueError, match="split_prior"):
        fit_instance_models(*args, instance_prior="split", split_prior=(0.0, 2.0), progress=False)


def test_an_unknown_instance_route_is_an_error():
    X = np.c_[np.cos(np.arange(4.0)), np.sin(np.arange(4.0))]
    with pytest.raises(ValueError, match="instance_route"):
        fit_instance_models([X], [np.ones((1, 4))], [np.array([0, 0, 1, 1])], ["c"], [0], instance_route="fast",
                            progress=False)


@pytest.mark.parametrize("prior", ["none", "split"])
def test_the_batched_optimum_is_at_least_the_per_fit_one_on_real_photographs(prior):
    """ETH-80 categories (4 instances x 16 azimuths a class, the balanced evaluation) on score-like
    targets (``test_gp_batch.eth80_stand_in``): 15 joint fits, without and with the instance prior,
    each batched optimum within 1e-6 of the per-fit one or higher (skips without ../shared/realdata)."""
    from tests.pipeline.method.test_gp_batch import eth80_stand_in

    Xs, Ys, labels = eth80_stand_in(instances=(1, 2, 3, 4))
    kw = dict(classes=["apple", "cow", "cup"], components=list(range(5)), restarts=2, progress=False,
              instance_prior=prior)
    _, batch = fit_instance_models(Xs, Ys, labels, instance_route="batch", **kw)
    _, each = fit_instance_models(Xs, Ys, labels, instance_route="per_fit", **kw)
    gaps = [(b["log_marginal_likelihood"] + b["log_prior"]) - (e["log_marginal_likelihood"] + e["log_prior"])
            for b, e in zip(batch, each)]
    assert len(gaps) == 15 and min(gaps) >= -1e-6, gaps
