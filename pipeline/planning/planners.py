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
registered with ``vf.register`` (``register_planner``) or through an entry point of the group
``viewfuse.planners``, in registration order. A planner is a class with a ``key``, a ``label``, a
``color`` and a ``note`` (the report's planning section shows them) and
``choose(belief, candidates, rng)``; ``make(eps, table)`` builds it (default: no arguments). The
contract is checked at registration (``problems``): one ``ExtensionError`` names every breach.
"""
from __future__ import annotations

import numpy as np

from pipeline.infra import extension as X
from pipeline.infra.registry import Registry
from pipeline.planning.eig import expected_information_gain

ENTRY_POINT_GROUP = "viewfuse.planners"


class Planner:
    """What a planner declares: its ``key`` (the population's tables and figures name it by it),
    ``label``, ``color`` and ``note`` (the report's), how it is built and how it chooses the next
    node (``rng``: the episode's own stream). ``name`` is the older spelling of ``key``, accepted
    and kept equal to it at registration."""
    key = ""
    label = ""          # the report's name (default: the key with spaces)
    color = "#CC79A7"   # its curves' colour in the report's figures
    note = ""           # one line on what it does
    name = ""           # deprecated spelling of ``key``

    @classmethod
    def make(cls, eps: np.ndarray, table=None) -> "Planner":
        """The planner for one episode, given the EIG draws and the models' ring table."""
        return cls()

    def choose(self, belief, candidates: dict, rng) -> str:
        raise NotImplementedError


_key_of = X.declared_key


def problems(cls) -> list[str]:
    """Every breach of the planner contract ``cls`` declares (empty: none)."""
    if not isinstance(cls, type):
        return [f"a planner is a class (a Planner subclass), got {type(cls).__name__}"]
    key = _key_of(cls)
    out = [None if isinstance(key, str) and key.isidentifier() else
           f"a planner needs a key that is an identifier, got {key!r:.60}",
           X.plain_name_problem(key) if isinstance(key, str) and key else None,
           X.text_problem("label", getattr(cls, "label", "")), X.text_problem("note", getattr(cls, "note", "")),
           X.color_problem(getattr(cls, "color", None))]
    choose = getattr(cls, "choose", None)
    out.append("has no choose(belief, candidates, rng)" if not callable(choose) else
               X.signature_problem(choose, "choose", "choose(belief, candidates, rng)", None, None, {}, None))
    make = getattr(cls, "make", None)
    out.append(X.signature_problem(make, "make", "make(eps, table)", None, None))
    return [p for p in out if p]


def register_planner(cls: type) -> type:
    """Class decorator: add a planner under ``cls.key`` (a key registered twice is an error; every
    breach of the contract, ``problems``, is one ``ExtensionError``)."""
    key = _key_of(cls) if isinstance(cls, type) else ""
    X.raise_problems("planner", key or getattr(cls, "__name__", repr(cls)[:40]), "register", problems(cls))
    old = PLANNERS.peek(key)
    if old is not None and old is not cls:
        raise X.ExtensionError.of("planner", key, "register",
                                  f"registered twice ({old.__module__}, {cls.__module__})")
    cls.key = cls.name = key
    if not getattr(cls, "label", ""):
        cls.label = key.replace("_", " ")
    PLANNERS.add(key, cls, module=cls.__module__, replace=True)
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
    key = "info_gain"
    label = "information gain"
    color = "#0072B2"
    note = "the candidate of largest expected information gain, predicted with the belief's localization samples"
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
    key = "known_pose"
    label = "information gain, known pose"
    color = "#56B4E9"
    note = "the same with the samples collapsed onto the pose estimate (sigma = 0)"
    known_pose = True


class RandomWalk(Planner):
    key = "random"
    label = "random walk"
    color = "#999999"
    note = "a uniform choice among the candidates"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(rng.integers(len(nodes)))]


class Orbit(Planner):
    key = "orbit"
    label = "orbit"
    color = "#E69F00"
    note = "the candidate that advances most counter-clockwise about the object"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        obj = belief.world.obj_xy
        here = belief.estimate(belief.visited[-1]) - obj
        there = belief.predicted(nodes, known_pose=True)[:, 0] - obj
        turn = np.arctan2(here[0] * there[:, 1] - here[1] * there[:, 0], here @ there.T)   # CCW advance
        return nodes[int(np.argmax(turn))]


class Hindsight(Planner):
    key = "hindsight"
    label = "hindsight (true class)"
    color = "#009E73"
    note = "the candidate whose real scores give the truth the largest posterior: an upper bound"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(np.argmax(belief.would_be(nodes)[:, belief.world.truth]))]


class Fixed(Planner):
    """Not a chooser: ``episode`` walks the world's track."""
    key = "fixed"
    label = "fixed track"
    color = "#000000"
    note = "the existing fixed track from the same start"


# registered in the order tables show them: info_gain, known_pose, random, fixed, orbit, hindsight
for _cls in (InfoGain, KnownPose, RandomWalk, Fixed, Orbit, Hindsight):
    register_planner(_cls)


def make_planner(name: str, eps: np.ndarray, table=None):
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; use one of {', '.join(PLANNERS)}")
    return PLANNERS[name].make(eps, table)
