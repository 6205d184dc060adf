"""Tests are isolated from installed plugins: the session pins every registry to its
built-ins (tests/conftest.py), so an entry point installed in the venv (stood in for here by a
monkeypatched ``importlib.metadata.entry_points``) changes no test's lists, and a test marked
``plugins`` sees it."""
from __future__ import annotations

import importlib.metadata

import pytest

import viewfuse as vf
from pipeline.evaluation.metrics import spec
from pipeline.infra.registry import pinned
from pipeline.method import registry as methods
from pipeline.planning.planners import PLANNERS, Planner

BUILTIN_PLANNERS = ["info_gain", "known_pose", "random", "fixed", "orbit", "hindsight"]


class Installed(Planner):
    key = "installed_planner"

    def choose(self, belief, candidates, rng):
        return sorted(candidates)[0]


class EP:
    group, name, value = "viewfuse.planners", "installed_planner", "somebody_elses:Installed"

    def load(self):
        return Installed


@pytest.fixture
def installed(monkeypatch):
    """A plugin 'installed in the venv': an entry point of viewfuse.planners, and the registry as a
    fresh process has it (entry points not loaded yet)."""
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group=None: [EP()] if group == EP.group else [])
    monkeypatch.setattr(PLANNERS, "_eps_loaded", False)
    yield
    PLANNERS.remove("installed_planner")


def test_the_registries_hold_the_builtins_only_whatever_is_installed(installed):
    assert pinned()
    assert list(PLANNERS) == BUILTIN_PLANNERS and "installed_planner" not in PLANNERS
    assert list(vf.planners()) == BUILTIN_PLANNERS
    assert all(methods.registered().is_builtin(k) for k in vf.methods(attribution=True))
    assert all(spec.METRICS.is_builtin(k) for k in spec.METRICS)


@pytest.mark.plugins
def test_a_test_marked_plugins_sees_the_installed_entry_points(installed, monkeypatch):
    assert not pinned()
    assert list(PLANNERS) == BUILTIN_PLANNERS + ["installed_planner"]
    monkeypatch.setenv("VIEWFUSE_BUILTINS_ONLY", "1")     # pinned again: loaded, yet hidden
    assert list(PLANNERS) == BUILTIN_PLANNERS and "installed_planner" not in PLANNERS
    with pytest.raises(KeyError):
        PLANNERS["installed_planner"]
