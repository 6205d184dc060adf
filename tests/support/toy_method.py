"""A toy fifth fusion method, defined entirely outside the product code: each candidate's own score
of every view, averaged over the dropout samples, tempered and multiplied (a pose-free baseline).
Tests register it with the ``toy_method`` fixture (and remove it after), and check that it reaches
every place the built-in methods reach."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.method import registry
from pipeline.method.fusion import simple_bayes

KEY = "toy_tempered"


class ToyTempered(registry.FusionMethod):
    key = KEY
    label = "Toy tempered Bayes (test)"
    short = "Toy tempered"
    color = "#117733"
    note = "multiplies the classifier's own scores raised to 0.5 (a test's own method)"
    needs = frozenset({"scores"})
    uses_poses = False
    simulation = True

    def fuse(self, t: registry.TrackInput) -> np.ndarray:
        return simple_bayes(np.sqrt(t.own.mean(axis=1)), return_log=True)

    def single_view(self, t: registry.TrackInput) -> np.ndarray:
        return simple_bayes(np.sqrt(t.own.mean(axis=1))[:, None, :], return_log=True)[:, 0]

    def simulate(self, models, draws, sim) -> np.ndarray:
        return simple_bayes(np.sqrt(np.clip(draws.noised, sim.simple_bayes_floor, None)))


@pytest.fixture
def toy_method():
    registry.register(ToyTempered)
    try:
        yield registry.get(KEY)
    finally:
        registry.unregister(KEY)
