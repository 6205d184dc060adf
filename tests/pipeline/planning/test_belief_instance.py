"""Planning's belief on the class models with an instance term: With Uncertainty + instance is the
engine call on the instance models, bit for bit; with no class holding a term it is With
Uncertainty's belief; without instance models it is refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.method.fusion import fuse_with_uncertainty
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.names import WU_INSTANCE
from pipeline.planning.belief import Belief
from pipeline.planning.population import models_for
from tests.pipeline.planning.ring import models, ring_world


def _instance(b: float) -> InstanceGPClassModels:
    m = models()
    labels = [np.arange(len(x)) % 3 for x in m.X]       # three training instances per class
    return InstanceGPClassModels.from_plain(m, labels, np.full(m.amplitude.shape, b), np.full(m.amplitude.shape, 2.0))


def _visit(b: Belief) -> list[np.ndarray]:
    return [b.update(n).copy() for n in ("v0", "v4", "v5")] + [b.would_be(["v1", "v2"])]


def test_the_instance_belief_is_the_engine_call_on_the_instance_models():
    world = ring_world(seed=2)
    inst = _instance(0.02)
    b = Belief(models(), world, sigma=0.2, n_x=5, key=(1,), method=WU_INSTANCE, instance_models=inst)
    got = _visit(b)
    X = np.stack([b.samples(n) for n in b.visited], axis=1)[None]
    Z = np.stack([world.dropout[n] for n in b.visited])[None]
    want = fuse_with_uncertainty(inst, world.inputs(X), Z, var_floor=b.var_floor, return_log=True, progress=False,
                                 threads=1)[:, -1]
    assert np.array_equal(got[2], want[0])
    plain = _visit(Belief(models(), world, sigma=0.2, n_x=5, key=(1,)))
    assert not np.allclose(got[2], plain[2])        # the shared deviation changes the belief


def test_no_term_is_with_uncertainty_bit_for_bit_and_missing_models_are_named():
    world = ring_world(truth=1, seed=4)
    got = _visit(Belief(models(), world, sigma=0.2, n_x=3, key=(2,), method=WU_INSTANCE, instance_models=_instance(0.0)))
    plain = _visit(Belief(models(), world, sigma=0.2, n_x=3, key=(2,)))
    for g, p in zip(got, plain):
        assert np.array_equal(g, p)
    with pytest.raises(ValueError, match="'with_uncertainty_instance' fuses on the class models with an instance term"):
        Belief(models(), world, method=WU_INSTANCE)
    with pytest.raises(ValueError, match="no 'instance_term' model bank"):
        models_for({"default": models()}, world, "instance_term")
    sub = models_for({"default": models(), "instance_term": _instance(0.02)}, world, "instance_term")
    assert isinstance(sub, InstanceGPClassModels) and sub.classes == ["a", "b"]
