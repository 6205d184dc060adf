"""Planning's belief on the class models with an instance term (its provider's models, ``provided``):
With Uncertainty + instance is the engine call on the instance models, bit for bit; with no class
holding a term it is With Uncertainty's belief; without them it is refused by name; a task reads
them from its world (the cell's), under the world's test-domain variance."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.method.fusion import fuse_with_uncertainty
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.names import WU_INSTANCE
from pipeline.planning.belief import Belief
from pipeline.method.methods.instance_term import INSTANCE_TERM
from pipeline.planning.population import LocSetting, Task, run_task
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
    b = Belief(models(), world, sigma=0.2, n_x=5, key=(1,), method=WU_INSTANCE, provided={INSTANCE_TERM: inst})
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
    got = _visit(Belief(models(), world, sigma=0.2, n_x=3, key=(2,), method=WU_INSTANCE,
                        provided={INSTANCE_TERM: _instance(0.0)}))
    plain = _visit(Belief(models(), world, sigma=0.2, n_x=3, key=(2,)))
    for g, p in zip(got, plain):
        assert np.array_equal(g, p)
    with pytest.raises(ValueError, match="'with_uncertainty_instance' needs the models of \\['instance_term'\\]"):
        Belief(models(), world, method=WU_INSTANCE)


def test_a_task_keeps_the_belief_on_its_worlds_instance_models_under_its_variance():
    variance = (0.03,)
    inst = _instance(0.02)
    world = dataclasses.replace(ring_world(seed=3), test_variance=variance, provided={INSTANCE_TERM: inst})
    s = LocSetting("randomized", (0.0, 0.0), 0.1, 0.1, 3)
    task = Task(world, 0, (s,), ("fixed",), 3, 1, 0.99, 4, 5, 1e-6, method=WU_INSTANCE)
    (_, _, ep), = run_task({"default": models()}, task)
    plain = models().with_test_variance(np.asarray(variance)[None, :])
    b = Belief(plain, world, bias=s.bias, est_sigma=s.est_sigma, sigma=s.sigma, n_x=s.n_x, key=(5, 0, s.name),
               method=WU_INSTANCE, provided={INSTANCE_TERM: inst.with_test_variance(np.asarray(variance)[None, :])})
    want = [b.update(n).copy() for n in ep.nodes]
    assert len(ep.nodes) >= 2 and np.array_equal(want[-1], ep.log_post[len(ep.nodes) - 1])
