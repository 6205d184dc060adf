"""The planner on a hand-built two-class world (tests/pipeline/planning/ring.py) and the
information gain against an exact integral."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from pipeline.planning.belief import Belief
from pipeline.planning.eig import entropy, expected_information_gain, standard_draws
from pipeline.planning.episode import run_episode
from pipeline.planning.graph import MoveGraph, candidate_paths
from pipeline.planning.planners import PLANNERS, InfoGain, KnownPose, make_planner
from tests.pipeline.planning.ring import SEPARATING, models, ring_world

EPS = standard_draws(64, 1, 0)


def belief(world, sigma=0.1, est_sigma=0.0, n_x=8, key=(0,)):
    return Belief(models(), world, bias=(0.0, 0.0), est_sigma=est_sigma, sigma=sigma, n_x=n_x, key=key)


def episode(name, world, seed=0, horizon=4, budget=4, confidence=0.999, **kw):
    return run_episode(belief(world, **kw), make_planner(name, EPS), "v0", budget=budget, confidence=confidence,
                       horizon=horizon, rng=np.random.default_rng(seed))


@pytest.mark.parametrize("truth", [0, 1])
def test_planner_goes_to_the_separating_view_first(truth):
    ep = episode("info_gain", ring_world(truth))
    assert ep.nodes[1] == SEPARATING
    gains = InfoGain(EPS)
    b = belief(ring_world(truth))
    b.update("v0")
    nodes = [f"v{i}" for i in range(1, 8)]
    g = gains.gains(b, nodes)
    assert nodes[int(np.argmax(g))] == SEPARATING and g.max() > 10 * np.delete(g, np.argmax(g)).max()


def test_random_walk_does_not_on_average():
    firsts = [episode("random", ring_world(), seed=s).nodes[1] for s in range(40)]
    share = np.mean([n == SEPARATING for n in firsts])
    assert share < 0.4                       # 1/7 expected: it goes anywhere
    assert len(set(firsts)) >= 4


def test_eig_equals_the_exact_integral_within_its_standard_error():
    m = models()
    rng = np.random.default_rng(3)
    th = np.pi + 0.2 * rng.standard_normal(3)                  # three localization samples near 180°
    inputs = np.stack([np.cos(th), np.sin(th)], -1)[None]       # (V=1, N=3, 2)
    lp0 = np.log(np.array([0.3, 0.7]))
    eps = standard_draws(4000, 1, 1)
    gain, se = expected_information_gain(m, inputs, lp0, eps, return_se=True)
    mu, var = m.marginal(inputs[0])                             # (N, C, F)
    mu, sd = mu[:, :, 0], np.sqrt(var[:, :, 0])
    z = np.linspace(mu.min() - 8 * sd.max(), mu.max() + 8 * sd.max(), 200001)
    dens = np.exp(-0.5 * ((z[:, None, None] - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi))   # (Z, N, C)
    mix = dens.mean(axis=1)                                     # (Z, C): p(z | c)
    joint = mix * np.exp(lp0)
    pz = joint.sum(axis=1)
    post = np.log(np.maximum(joint, 1e-300)) - np.log(np.maximum(pz, 1e-300))[:, None]
    exact = entropy(lp0) - np.sum(pz * entropy(post)) * (z[1] - z[0])
    assert 0 < se[0] < 0.02
    assert abs(gain[0] - exact) < 4 * se[0]


def test_eig_is_zero_where_the_classes_agree():
    m = models()
    inputs = np.array([[[1.0, 0.0]]])                           # 0°: both classes score 0.5
    g = expected_information_gain(m, inputs, np.log([0.5, 0.5]), standard_draws(256, 1, 0))
    assert abs(g[0]) < 0.05


@pytest.mark.parametrize("name", [p for p in PLANNERS if p != "fixed"])
def test_planners_move_only_along_the_graph(name):
    world = ring_world(chords=True)
    for seed in range(3):
        ep = episode(name, world, seed=seed, horizon=1, budget=8, confidence=None, sigma=0.2)
        assert len(ep.nodes) == 8
        for prev, path in zip(ep.nodes, ep.paths):
            hops = (prev,) + path
            assert all(world.graph.linked(a, b) for a, b in pairwise(hops)), (name, hops)


def test_candidates_fall_back_to_the_nearest_unvisited_views():
    g = MoveGraph.from_moves({"a": {"left": "b"}, "b": {"left": "c"}, "c": {"left": "d"}, "d": {}})
    assert candidate_paths(g, "a", {"a", "c", "d"}, {"a"}, 1) == {"c": ("b", "c")}
    assert candidate_paths(g, "a", {"a"}, {"a"}, 1) == {}
    assert candidate_paths(g, "a", {"b", "c"}, {"a"}, 2) == {"b": ("b",), "c": ("b", "c")}


def test_known_pose_is_the_special_case_sigma_zero():
    world = ring_world()
    for est_sigma in (0.0, 0.2):   # with sigma = 0 both plan with the estimates alone
        a = episode("info_gain", world, sigma=0.0, est_sigma=est_sigma, budget=5, confidence=None)
        b = episode("known_pose", world, sigma=0.0, est_sigma=est_sigma, budget=5, confidence=None)
        assert a.nodes == b.nodes
        np.testing.assert_array_equal(a.log_post, b.log_post)
    # With sigma > 0 the known-pose gains are the information gain of localization samples told
    # sigma = 0 (copies of the estimate), under the same class posterior.
    b_sig, b_zero = belief(world, sigma=0.3, est_sigma=0.2), belief(world, sigma=0.0, est_sigma=0.2)
    b_sig.update("v0")
    b_zero.update("v0")
    nodes = ["v1", "v3", "v4", "v6"]
    zero = expected_information_gain(b_sig.models, world.inputs(b_zero.predicted(nodes)), b_sig.log_post, EPS)
    np.testing.assert_allclose(KnownPose(EPS).gains(b_sig, nodes), zero, rtol=0, atol=1e-12)
    assert not np.allclose(InfoGain(EPS).gains(b_sig, nodes), zero, rtol=0, atol=1e-6)


def test_planning_is_deterministic_for_a_seed():
    world = ring_world(chords=True)
    for name in PLANNERS:
        a = episode(name, world, seed=5, horizon=1, budget=6, confidence=None, sigma=0.3, est_sigma=0.3)
        b = episode(name, world, seed=5, horizon=1, budget=6, confidence=None, sigma=0.3, est_sigma=0.3)
        assert a.nodes == b.nodes
        np.testing.assert_array_equal(a.log_post, b.log_post)
    paths = {tuple(episode("random", world, seed=s, horizon=1, budget=6, confidence=None).nodes) for s in range(6)}
    assert len(paths) > 1


def test_episode_stops_at_the_confidence_and_fixed_follows_the_track():
    world = ring_world()
    ep = episode("info_gain", world, confidence=0.9, budget=6)
    k = int(np.argmax(np.exp(ep.log_post).max(axis=1) >= 0.9))
    assert ep.measured[: k + 1].all() and not ep.measured[k + 1:].any()
    np.testing.assert_array_equal(ep.log_post[k:], np.repeat(ep.log_post[k:k + 1], 6 - k, axis=0))
    fx = episode("fixed", world, confidence=None, budget=6)
    assert fx.nodes == list(world.track) and fx.measured.sum() == len(world.track)


def test_hindsight_is_an_upper_bound_on_the_truth_at_each_next_step():
    world = ring_world(chords=True)
    h = episode("hindsight", world, horizon=1, budget=2, confidence=None)
    for name in ("info_gain", "random", "orbit"):
        other = episode(name, world, horizon=1, budget=2, confidence=None)
        assert h.log_post[1, world.truth] >= other.log_post[1, world.truth] - 1e-12


def test_ring_table_matches_the_gp_predictive():
    from pipeline.planning.eig import RingTable
    from tests.bench.bench_planning import class_models

    for m in (models(), class_models(C=3, F=2)):
        th = np.random.default_rng(0).uniform(-4, 4, 300)
        x = np.stack([np.cos(th), np.sin(th)], -1)
        mu, var = m.marginal(x)
        tmu, tvar = RingTable(m)(x)
        scale = m.amplitude.max()
        assert np.max(np.abs(tmu - mu)) < 1e-3 * scale + 1e-9
        assert np.max(np.abs(tvar - var)) < 1e-3 * scale + 1e-9
        lp = np.log(np.full(m.n_classes, 1 / m.n_classes))
        eps = standard_draws(64, m.n_components, 0)
        exact = expected_information_gain(m, x[:12].reshape(3, 4, 2), lp, eps)
        fast = expected_information_gain(m, x[:12].reshape(3, 4, 2), lp, eps, table=RingTable(m))
        np.testing.assert_allclose(fast, exact, atol=2e-3)
