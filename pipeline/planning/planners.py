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
"""
from __future__ import annotations

import numpy as np

from pipeline.planning.eig import expected_information_gain

PLANNERS = ("info_gain", "known_pose", "random", "fixed", "orbit", "hindsight")


class InfoGain:
    name = "info_gain"
    known_pose = False

    def __init__(self, eps: np.ndarray, table=None):
        self.eps, self.table = eps, table     # table: the models' ``eig.RingTable`` (None: exact GPs)

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


class RandomWalk:
    name = "random"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(rng.integers(len(nodes)))]


class Orbit:
    name = "orbit"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        obj = belief.world.obj_xy
        here = belief.estimate(belief.visited[-1]) - obj
        there = belief.predicted(nodes, known_pose=True)[:, 0] - obj
        turn = np.arctan2(here[0] * there[:, 1] - here[1] * there[:, 0], here @ there.T)   # CCW advance
        return nodes[int(np.argmax(turn))]


class Hindsight:
    name = "hindsight"

    def choose(self, belief, candidates: dict, rng) -> str:
        nodes = sorted(candidates)
        return nodes[int(np.argmax(belief.would_be(nodes)[:, belief.world.truth]))]


class Fixed:
    """Not a chooser: ``episode`` walks the world's track."""
    name = "fixed"


def make_planner(name: str, eps: np.ndarray, table=None):
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; use one of {', '.join(PLANNERS)}")
    return {"info_gain": lambda: InfoGain(eps, table), "known_pose": lambda: KnownPose(eps, table),
            "random": RandomWalk,
            "fixed": Fixed, "orbit": Orbit, "hindsight": Hindsight}[name]()
