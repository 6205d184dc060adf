"""One check of every fusion method's output (pipeline/method/output_check.py), wherever a method
is called: a misshapen, NaN, +inf or unnormalised posterior and a method that raises are named
by the method's key; -inf (an underflowed probability) passes; the grid's calls go through it,
and a method with only ``fuse`` (no single_view) runs through the grid's single-view table."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.method.method_base import FusionMethod, TrackInput
from pipeline.method.output_check import MethodOutputError, call_checked, check_output

K, C = 4, 3
GOOD = np.log(np.full((K, C), 1 / C))


@pytest.mark.parametrize("out, words", [
    (np.full((K, C), np.nan), "NaN"),
    (np.where(np.eye(K, C) > 0, np.inf, -1.0), "+inf"),
    (np.full((K, C), 3.0), "not normalised"),
    (np.log(np.full((K, C), 0.4)), "sum to 1.2"),
    (np.full((K, C), -np.inf), "-inf for every class"),
    (np.zeros((K + 2, C + 1)), "shape (6, 4)"),
    (np.zeros((K, C, 1)), "shape (4, 3, 1)"),
    (np.zeros((K, 0)), "shape (4, 0)"),
    ("not an array", "str"),
])
def test_what_no_posterior_can_be_is_named_with_the_key(out, words):
    with pytest.raises(MethodOutputError) as e:
        check_output("toy_key", out, (K, C))
    assert "'toy_key'" in str(e.value) and words in str(e.value)


def test_an_underflowed_probability_passes_and_float32_rounding_too():
    lp = np.array([[0.0, -np.inf, -np.inf], [np.log(0.5), np.log(0.5), -np.inf]])   # -inf entries
    assert check_output("k", lp, (2, C)).shape == (2, C)
    p = np.random.default_rng(0).dirichlet(np.ones(C), size=50).astype(np.float32)
    check_output("k", np.log(p), (None, C))


class _Toy(FusionMethod):
    key = "toy_check"
    label = short = "Toy"
    needs = frozenset({"scores"})
    uses_poses = False
    result = GOOD

    def fuse(self, t):
        if isinstance(self.result, Exception):
            raise self.result
        return self.result


def _track(k=K):
    rng = np.random.default_rng(1)
    return TrackInput(dropout=rng.normal(size=(k, 2, 2)), own=rng.dirichlet(np.ones(C), size=(k, 2)),
                      estimates=np.zeros((5, k, 2)))


@pytest.mark.parametrize("result, words", [
    (IndexError("index 9 is out of bounds"), "failed: IndexError: index 9"),
    (GOOD[:-1], "shape (3, 3); expected (4, 3)"),
    (GOOD + 3.0, "not normalised"),
])
def test_a_method_call_names_the_method(result, words):
    m = _Toy()
    m.result = result
    for hook in ("fuse", "fuse_with_extras"):
        with pytest.raises(MethodOutputError, match="'toy_check'") as e:
            call_checked(m, hook, _track())
        assert words in str(e.value) and hook in str(e.value)


def test_pose_using_output_needs_the_realization_axis():
    m = _Toy()
    m.uses_poses = True
    with pytest.raises(MethodOutputError, match=r"expected \(5, 4, 3\)"):
        call_checked(m, "fuse", _track())          # dropped the R axis
    m.result = np.broadcast_to(GOOD, (5, K, C))
    assert call_checked(m, "fuse", _track()).shape == (5, K, C)


def test_simple_bayes_with_one_own_row_short_is_refused():
    from pipeline.method import registry

    sb = registry.get("simple_bayes")
    t = _track()
    short = TrackInput(dropout=t.dropout, own=t.own[:-1], estimates=t.estimates)
    with pytest.raises(MethodOutputError, match="'simple_bayes'.*shape \\(3, 3\\); expected \\(4, 3\\)"):
        call_checked(sb, "fuse", short)
    assert call_checked(sb, "single_view", t).shape == (K, C)


def test_the_grid_checks_every_call_and_a_fuse_only_method_has_no_difficulty_entry():
    from pipeline.evaluation.grid import experiments as E
    from pipeline.method import registry

    rng = np.random.default_rng(2)
    track = E.TrackData(images=("a",) * K, cam_xy=rng.normal(size=(K, 2)) + 3, obj_xy=np.zeros(2), yaw=0.0,
                        dropout=rng.normal(size=(K, 2, 2)), own=rng.dirichlet(np.ones(C), size=(K, 2)))
    registry.register(_Toy)
    try:
        diff = E.single_view_first(None, track, 0)
        assert "toy_check" not in diff and diff["simple_bayes"] >= 0      # no single_view: no entry
        t = E.track_input(None, track, var_floor=1e-6)
        posts, _ = E.pose_free(t)
        assert posts["toy_check"].shape == (K, C)
        registry.get("toy_check").result = np.full((K, C), np.nan)
        with pytest.raises(MethodOutputError, match="'toy_check' \\(fuse_with_extras\\).*NaN"):
            E.pose_free(t)
        with pytest.raises(MethodOutputError, match="'toy_check' \\(fuse\\).*NaN"):
            E.fuse_track(None, track, np.zeros((2, K, 2)), np.zeros((2, 1, K, 2)), var_floor=1e-6)
    finally:
        registry.unregister("toy_check")


@pytest.mark.parametrize("flag, hook", [("simulation", "simulate"), ("planning", "fuse_tracks")])
def test_a_flag_without_its_hook_is_refused_at_registration(flag, hook):
    from pipeline.method import registry

    cls = type("Flagged", (_Toy,), {"key": "toy_flagged", flag: True})
    with pytest.raises(ValueError, match=f"{flag} = True needs {hook}"):
        registry.register(cls)
    assert registry.get("toy_flagged") is None


def test_the_simulations_probabilities_are_checked_by_the_same_rule():
    from pipeline.method.output_check import check_probabilities

    p = np.full((2, K, C), 1 / C)
    assert check_probabilities("k", p, (2, K, C)) is p                        # returned as it is
    for bad, words in ((p * 2, "not normalised"), (p - 0.5, "negative"), (p[:, :, :2], "shape")):
        with pytest.raises(MethodOutputError, match=f"'k' \\(simulate\\).*{words}"):
            check_probabilities("k", bad, (2, K, C))
