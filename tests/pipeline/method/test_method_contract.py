"""The method contract (pipeline/method/call_guard.py, output_check.call_checked): a method reads
read-only views, so one that writes into ``t.own`` / ``t.dropout`` fails, named, and cannot change
another method's numbers or the caller's arrays; a method that blocks is stopped and named, in
``vf.fuse`` and in a forked worker (as the evaluate stage's cells run); a ``SystemExit`` is
contained and named; only real floating outputs are accepted."""
from __future__ import annotations

import functools
import multiprocessing
import threading

import numpy as np
import pytest

import viewfuse as vf
from pipeline.infra.extension import ExtensionError
from pipeline.method import call_guard
from pipeline.method.call_guard import MethodTimeout
from pipeline.method.method_base import FusionMethod, TrackInput
from pipeline.method.output_check import MethodOutputError, call_checked
from pipeline.method.registry import register, unregister

K, C, N_S = 3, 3, 2


@functools.cache
def world():
    rng = np.random.default_rng(0)
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    samples = {n: (ang, np.stack([0.5 + 0.3 * np.cos(ang - c), 0.5 - 0.2 * np.cos(ang - c)], 1)
                   + rng.normal(0, 0.02, (8, 2))) for c, n in enumerate(("mug", "bowl", "can"))}
    models = vf.fit_models(samples, restarts=0)
    cams = 2.0 * np.stack([np.cos(np.linspace(0, 1, K)), np.sin(np.linspace(0, 1, K))], 1)
    return models, dict(cameras=cams, dropout=rng.normal(0.5, 0.1, (K, N_S, 2)),
                        own=rng.dirichlet(np.ones(C), (K, N_S)), sigma=0.2, n_x=4, seed=0, max_seconds=None)


class _Outside(FusionMethod):
    label = short = "outside (test)"
    needs = frozenset({"scores"})
    uses_poses = False
    do = "nothing"

    def fuse(self, t):
        if self.do == "write":
            t.own[...] = 1.0        # what a careless method does: writes into what every method reads
            t.dropout[...] = 0.0
        elif self.do == "block":
            threading.Event().wait()
        elif self.do == "exit":
            raise SystemExit(0)
        return {"complex": np.zeros((K, C), complex) - np.log(C), "text": np.full((K, C), "-1.0986"),
                "object": np.full((K, C), -np.log(C), dtype=object)}.get(self.do, np.full((K, C), -np.log(C)))


@pytest.fixture
def outside(request):
    cls = type("Outside", (_Outside,), {"key": "outside_" + request.param, "do": request.param})
    register(cls)
    try:
        yield cls.key
    finally:
        unregister(cls.key)


@pytest.mark.parametrize("outside", ["write"], indirect=True)
def test_a_method_that_writes_its_input_is_named_and_changes_nothing(outside):
    models, track = world()
    mine = {k: np.array(v, copy=True) for k, v in track.items() if isinstance(v, np.ndarray)}
    before = {m: vf.fuse(m, models, **track) for m in ("with_uncertainty", "model_based", "simple_bayes")}
    with pytest.raises(MethodOutputError, match=rf"fusion method '{outside}' \(fuse\) failed: ValueError: .*read-only"):
        vf.fuse(outside, models, **track)
    for k, v in mine.items():       # the caller's arrays, unchanged
        np.testing.assert_array_equal(track[k], v)
    for m, post in before.items():  # the built-ins' results, bit for bit
        np.testing.assert_array_equal(vf.fuse(m, models, **track), post)


@pytest.mark.parametrize("outside", ["write"], indirect=True)
def test_one_track_input_shared_by_every_method_stays_as_it_was(outside):
    """The grid hands every method the same ``TrackInput`` (experiments.fuse_track): a writer's call
    fails and the next method reads what the first did."""
    own = np.random.default_rng(1).dirichlet(np.ones(C), (K, N_S))
    t = TrackInput(dropout=np.zeros((K, N_S, 2)), own=own.copy())
    sb = vf.method("simple_bayes")
    first = call_checked(sb, "fuse", t)
    with pytest.raises(MethodOutputError, match=outside):
        call_checked(vf.method(outside), "fuse", t)
    np.testing.assert_array_equal(t.own, own)
    np.testing.assert_array_equal(call_checked(sb, "fuse", t), first)


@pytest.mark.parametrize("outside", ["block"], indirect=True)
def test_a_method_that_blocks_is_stopped_and_named_in_fuse(outside):
    models, track = world()
    with pytest.raises(MethodTimeout, match=rf"fusion method '{outside}' \(fuse\): did not return within 0.5 s"):
        vf.fuse(outside, models, **track, time_limit=0.5)
    assert isinstance(MethodTimeout("x"), ExtensionError)


def _cell(key):
    """What a forked worker runs: one method call under the limit the parent set before forking."""
    t = TrackInput(dropout=np.zeros((K, N_S, 2)), own=np.full((K, N_S, C), 1 / C))
    try:
        call_checked(vf.method(key), "fuse", t)
    except ExtensionError as e:
        return type(e).__name__, str(e)
    return None


@pytest.mark.parametrize("outside", ["block"], indirect=True)
def test_a_method_that_blocks_in_a_forked_worker_is_stopped_and_named(outside):
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("no fork on this platform: the evaluate stage's workers are forked")
    old = call_guard.set_time_limit(0.5)
    try:
        with multiprocessing.get_context("fork").Pool(1) as pool:
            kind, text = pool.apply(_cell, (outside,))
    finally:
        call_guard.set_time_limit(old)
    assert kind == "MethodTimeout" and f"'{outside}'" in text and "run.method_seconds" in text


def test_the_evaluate_stage_default_limit_is_a_setting():
    from pipeline.infra.config.inputs import RunConfig

    assert RunConfig().method_seconds > 0 and call_guard.TIME_LIMIT == 0.0   # set by the stage only


@pytest.mark.parametrize("outside", ["exit"], indirect=True)
def test_a_system_exit_is_contained_and_named(outside):
    models, track = world()
    with pytest.raises(MethodOutputError, match=rf"'{outside}' \(fuse\) failed: SystemExit"):
        vf.fuse(outside, models, **track)


@pytest.mark.parametrize("outside", ["complex", "text", "object"], indirect=True)
def test_only_real_floating_outputs_are_accepted(outside):
    models, track = world()
    with pytest.raises(MethodOutputError, match=rf"'{outside}' \(fuse\) returned an array of dtype"):
        vf.fuse(outside, models, **track)


def test_an_outer_timer_that_fires_later_is_rearmed():
    import signal

    fired = []
    old = signal.signal(signal.SIGALRM, lambda *_: fired.append(1))
    try:
        signal.setitimer(signal.ITIMER_REAL, 30.0)
        with call_guard.time_limit(5.0, "fusion method", "k", "fuse"):
            pass
        left, _ = signal.getitimer(signal.ITIMER_REAL)
        assert 0 < left <= 30.0 and not fired
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
