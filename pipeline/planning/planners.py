"""The planners: each chooses the next measurement node from the candidates the graph offers
(``graph.candidate_paths``), given the belief. All see the same candidates and the same start.

- ``info_gain``: the candidate of largest expected information gain (``eig``), predicted with the
  belief's localization samples (the pose the robot believes, with its uncertainty);
- ``known_pose``: the same with the samples collapsed onto the pose estimate (sigma = 0: what
  planners that assume a known pose do);
- ``random``: a uniform choice (a random walk over the measurement nodes);
- ``fixed``: the existing fixed track from the same start (its views in order; not bound to the
  move graph, as the evaluate stage's tracks are not);
- ``orbit``: keep the object in view and go around it: the candidate that advances most
  counter-clockwise about the object (bearing from the estimated pose), the least backwards when
  none advances;
- ``hindsight``: the candidate whose real recorded scores, fused, give the truth the largest
  posterior: an upper bound that uses the true class and scores no planner can know.
Ties go to the first candidate in name order.

``PLANNERS`` is the planner registry (``pipeline.infra.registry``): these six first, then any
registered with ``@register_planner`` (``vf.register_planner``) or through an entry point of the
group ``viewfuse.planners``, in registration order. A planner is a class with a ``name`` and
``choose(belief, candidates, rng)``; ``make(eps, table)`` builds it (default: no arguments).
"""
from __future__ import annotations

import numpy as np

from pipeline.infra.registry import Registry, RegistryError
from pipeline.planning.eig import expected_information_gain

ENTRY_POINT_GROUP = "viewfuse.planners"


class Planner:
    """What a planner declares: its ``name`` (the population's tables and figures show it), how it
    is built and how it chooses the next node (``rng``: the episode's own stream)."""
    name = ""

    @classmethod
    def make(cls, eps: np.ndarray, table=None) -> "Planner":
        """The planner for one episode, given the EIG draws and the models' ring table."""
        return cls()

    def choose(self, belief, candidates: dict, rng) -> str:
        raise NotImplementedError


def register_planner(cls: type) -> type:
    """Class decorator: add a planner under ``cls.name`` (a name registered twice is an error)."""
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"{cls!r}: a planner needs a name that is an identifier, got {name!r}")
    if not callable(getattr(cls, "choose", None)):
        raise ValueError(f"planner {name!r} has no choose(belief, candidates, rng)")
    old = PLANNERS.peek(name)
    if old is not None and old is not cls:
        raise RegistryError(f"planner {name!r} is registered twice ({old.__module__}, {cls.__module__})")
    PLANNERS.add(name, cls, module=cls.__module__, replace=True)
    return cls


def unregister_planner(name: str) -> None:
    PLANNERS.remove(name)


def _adopt(name: str, obj, module: str) -> None:
    if not isinstance(obj, type):
        raise TypeError(f"entry point {name!r} of {ENTRY_POINT_GROUP!r} names {obj!r}: not a module or a planner class")
    register_planner(obj)


# name -> planner class; the built-ins (this module) first, in the order below
PLANNERS: Registry[type] = Registry("planner", ENTRY_POINT_GROUP, __name__, static=(__name__,), adopt=_adopt)


class InfoGain(Planner):
    name = "info_gain"
    known_pose = False

    def __init__(self, eps: np.ndarray, table=None):
        self.eps, self.table = eps, table     # table: the models' ``eig.RingTable`` (None: exact GPs)

    @classmethod
    def make(cls, eps, table=None):
        return cls(eps, table)

    def gains(self, belief, nodes) -> np.ndarray:
        pos = belief.predicted(nodes, known_pose=self.known_pose)
        return expected_information_gain(belief.models, belief.world.inputs(pos), belief.log_post, self.eps,
                                         table=self.table)

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(np.argmax(self.gains(belief, nodes)))]


class KnownPose(InfoGain):
    name = "known_pose"
    known_pose = True


class RandomWalk(Planner):
    name = "random"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(rng.integers(len(nodes)))]


class Orbit(Planner):
    name = "orbit"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        obj = belief.world.obj_xy
        here = belief.estimate(belief.visited[-1]) - obj
        there = belief.predicted(nodes, known_pose=True)[:, 0] - obj
        turn = np.arctan2(here[0] * there[:, 1] - here[1] * there[:, 0], here @ there.T)   # CCW advance
        return nodes[int(np.argmax(turn))]


class Hindsight(Planner):
    name = "hindsight"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(np.argmax(belief.would_be(nodes)[:, belief.world.truth]))]


class Fixed(Planner):
    """Not a chooser: ``episode`` walks the world's track."""
    name = "fixed"


# registered in the order tables show them: info_gain, known_pose, random, fixed, orbit, hindsight
for _cls in (InfoGain, KnownPose, RandomWalk, Fixed, Orbit, Hindsight):
    register_planner(_cls)


def make_planner(name: str, eps: np.ndarray, table=None):
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; use one of {', '.join(PLANNERS)}")
    return PLANNERS[name].make(eps, table)
