"""The ``[plan]`` section: information-gain view planning on the AVD move graph
(``pipeline.planning``, docs/planning.md), run by the evaluate stage."""
from __future__ import annotations

from dataclasses import dataclass

from pipeline.infra.config.fields import SEED_MAX
from pipeline.infra.config.fields import setting as _f


@dataclass(frozen=True)
class PlanConfig:
    enabled: bool = _f(True, doc="run the view-planning evaluation in the evaluate stage")
    budget: int = _f(10, lo=2, hi=200, doc="step budget: measurements per episode, the start's included")
    horizon: int = _f(1, lo=1, hi=10, doc="moves of the graph the next measurement may be away")
    starts: int = _f(4, lo=1, hi=1000, doc="start nodes per target: the first views of its first fixed tracks")
    eig_samples: int = _f(64, lo=2, hi=100000, doc="Monte-Carlo draws per candidate class for the information gain")
    confidence: float = _f(0.9, lo=0.5, hi=1.0, doc="the robot stops and decides at max P >= this")
    sigma_m: float = _f(0.3, lo=0.0, hi=10.0, doc="the randomized setting's pose error std (and the std told "
                                                   "to With Uncertainty); the biased one is evaluate.biased's")
    seed: int = _f(0, lo=0, hi=SEED_MAX, doc="seeds the random walk, the estimates and the Monte-Carlo draws")
