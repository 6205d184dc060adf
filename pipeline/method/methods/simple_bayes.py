"""Simple Bayes (Patten et al.): the classifier's own score of each candidate multiplied view after
view; ignores the viewpoint and the poses (``pipeline.method.fusion.simple_bayes``)."""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import simple_bayes
from pipeline.method.names import SIMPLE_BAYES
from pipeline.method.method_base import FusionMethod, TrackInput, register


def to_simplex(scores: np.ndarray, floor: float) -> np.ndarray:
    """Simple Bayes needs probability vectors: clip each score to >= ``floor`` (a Gaussian
    measurement can go negative, and a zero would rule a class out for good), then normalise."""
    s = np.maximum(np.asarray(scores, float), float(floor))
    return s / s.sum(axis=-1, keepdims=True)


@register
class SimpleBayes(FusionMethod):
    key = SIMPLE_BAYES
    label = "Simple Bayes"
    short = "Simple Bayes"
    color = "#009E73"
    note = ("multiplies the classifier's own score of each candidate view after view; ignores the viewpoint and "
            "the poses. It reads other numbers than the GP methods (each candidate's own score component, not "
            "the GP components): the view-independent Gaussian is the baseline on the same numbers")
    needs = frozenset({"scores"})
    uses_poses = False
    simulation = True

    def fuse(self, t: TrackInput) -> np.ndarray:
        return simple_bayes(t.own.mean(axis=1), return_log=True)

    def single_view(self, t: TrackInput) -> np.ndarray:
        return simple_bayes(t.own.mean(axis=1)[:, None, :], return_log=True)[:, 0]

    def simulate(self, models, draws, sim) -> np.ndarray:
        return simple_bayes(to_simplex(draws.noised, sim.simple_bayes_floor))
