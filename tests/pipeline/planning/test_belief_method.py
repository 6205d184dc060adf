"""Planning's belief update goes through the fusion-method registry: With Uncertainty's update is
the engine call itself, bit for bit; a method registered with ``planning`` is used as it is; one
without it is refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.method import registry
from pipeline.method.fusion import fuse_with_uncertainty, log_prior
from pipeline.method.method_base import FusionMethod, TrackInput
from pipeline.planning.belief import Belief
from tests.pipeline.planning.ring import models, ring_world


def _direct(b: Belief, tracks: list[list[str]]) -> np.ndarray:
    """The belief update written out against the engine (the pre-registry literal call)."""
    X = np.stack([np.stack([b.samples(n) for n in t], axis=1) for t in tracks])
    Z = np.stack([np.stack([b.world.dropout[n] for n in t]) for t in tracks])
    return fuse_with_uncertainty(b.models, b.world.inputs(X), Z, var_floor=b.var_floor, return_log=True,
                                 progress=False, threads=1)[:, -1]


@pytest.mark.parametrize("seed", [0, 3])
def test_the_registered_with_uncertainty_update_is_the_engine_call_bit_for_bit(seed):
    world = ring_world(truth=seed % 2, seed=seed)
    b = Belief(models(), world, bias=(0.1, -0.05), est_sigma=0.05, sigma=0.2, n_x=7, key=(seed,))
    assert b.method.key == registry.REFERENCE
    for node in ("v0", "v1", "v4"):
        b.update(node)
        assert np.array_equal(b.log_post, _direct(b, [b.visited])[0])
    rest = [n for n in world.xy if n not in b.visited]
    assert np.array_equal(b.would_be(rest), _direct(b, [b.visited + [n] for n in rest]))


class _Flat(FusionMethod):
    """A toy planning method: every step keeps the uniform prior; it records what it was given."""
    key = "toy_flat_planner"
    label = short = "Flat"
    planning = True
    seen: list = []

    def fuse_tracks(self, t: TrackInput) -> np.ndarray:
        type(self).seen.append((t.dropout.shape, t.samples.shape, t.estimates.shape, t.threads))
        r, k = t.dropout.shape[:2]
        return np.broadcast_to(log_prior(None, len(t.gp.classes)), (r, k, len(t.gp.classes))).copy()


def test_a_method_registered_for_planning_updates_the_belief_and_others_are_refused():
    registry.register(_Flat)
    try:
        world = ring_world()
        b = Belief(models(), world, sigma=0.2, n_x=4, method=_Flat.key)
        b.update("v0")
        b.update("v4")
        np.testing.assert_allclose(b.posterior, [0.5, 0.5])
        assert b.would_be(["v1", "v2", "v3"]).shape == (3, 2)
        # two updates of 1 and 2 views, then three candidate tracks of 3 views; N_s = 5, F = 1
        assert _Flat.seen == [((1, 1, 5, 1), (1, 4, 1, 2), (1, 1, 2), 1), ((1, 2, 5, 1), (1, 4, 2, 2), (1, 2, 2), 1),
                              ((3, 3, 5, 1), (3, 4, 3, 2), (3, 3, 2), 1)]
    finally:
        registry.unregister(_Flat.key)
    with pytest.raises(ValueError, match="'simple_bayes' is not a registered method that applies to planning"):
        Belief(models(), ring_world(), method="simple_bayes")
    with pytest.raises(ValueError, match="'toy_flat_planner'"):
        Belief(models(), ring_world(), method=_Flat.key)
