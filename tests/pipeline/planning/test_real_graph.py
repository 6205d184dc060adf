"""The planners on a real AVD move graph (Home_001_1's annotations.json, metadata only), with
hand-made scores: every move they make is an edge of the real graph. Skips without the real data."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from loaders.avd_paths import scan_paths
from pipeline.planning.belief import Belief
from pipeline.planning.eig import standard_draws
from pipeline.planning.episode import run_episode
from pipeline.planning.graph import MoveGraph
from pipeline.planning.planners import make_planner
from pipeline.planning.world import World
from tests.loaders.realdata import need
from tests.pipeline.planning.ring import models


@pytest.mark.slow   # reading the real scan's metadata takes most of a minute
def test_planners_stay_on_the_real_graph():
    sp = scan_paths(need("avd"), "Home_001_1")
    graph = MoveGraph.from_moves({n: node.moves for n, node in sp.nodes.items()})
    inst = max(sp.instances.values(), key=lambda i: len(i.boxes))
    views = sorted(inst.boxes)
    rng = np.random.default_rng(0)
    xy = {n: np.asarray(sp.nodes[n].position, float) for n in views}
    drop = {n: 0.5 + 0.02 * rng.standard_normal((4, 1)) for n in views}
    world = World(inst.instance, "Home_001_1", ("a", "b"), (0,), 0, graph, xy, drop, np.asarray(inst.xy, float),
                  0.0, tuple(views[:3]))
    assert all(len(graph.neighbours(n)) <= 6 for n in views)
    for name in ("info_gain", "random", "orbit"):
        b = Belief(models(), world, sigma=0.2, n_x=5, key=(1,))
        ep = run_episode(b, make_planner(name, standard_draws(16, 1, 0)), views[0], budget=6, confidence=None,
                         horizon=1, rng=np.random.default_rng(2))
        assert len(ep.nodes) >= 2
        for prev, path in zip(ep.nodes, ep.paths):
            assert all(graph.linked(a, c) for a, c in pairwise((prev,) + path)), (name, prev, path)
            assert path[-1] in world.visible
