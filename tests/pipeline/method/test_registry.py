"""The fusion-method registry: the built-ins' identity, the registry path against the paper's
literal equations (tests/support/literal_paper.py), registration errors, and a toy method
registered from here reaching the single-track fusion and the simulation."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.metrics import labels
from pipeline.evaluation.simulation import scenarios as S
from pipeline.method import registry
from pipeline.method.geometry import sample_localization
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models
from tests.support.literal_paper import literal_model_based, literal_uncertainty, literal_view_independent
from tests.support.toy_method import KEY, ToyTempered, toy_method  # noqa: F401 (fixture)

BUILTIN = ("with_uncertainty", "model_based", "simple_bayes", "dirichlet")


def test_builtins_in_order_each_with_its_own_identity():
    assert registry.keys()[:4] == BUILTIN
    assert registry.keys(attribution=True)[:6] == BUILTIN[:3] + labels.ATTRIBUTION + BUILTIN[3:]
    ms = registry.methods()
    for attr in ("label", "short", "color"):
        assert len({getattr(m, attr) for m in ms}) == len(ms), attr
    assert all(m.note for m in ms)
    assert registry.comparisons()[:3] == tuple(("with_uncertainty", b) for b in BUILTIN[1:])
    assert labels.method_label("dirichlet") == registry.get("dirichlet").label
    assert labels.method_label("nope") == "nope" and labels.method_color("nope") == labels.UNKNOWN_COLOR
    assert S.methods() == BUILTIN[:3]   # the Dirichlet models softmax vectors: not in the simulation


def _case(R=2, n_x=3, K=4, n_s=3, sigma=0.2):
    models = ring_models(C=3, F=2)
    base = make_track(models, truth=1, K=K, n_s=n_s, seed=3)
    own = np.random.default_rng(4).dirichlet(np.ones(3), size=(K, n_s))
    track = E.TrackData(base.images, base.cam_xy, base.obj_xy, base.yaw, base.dropout, own=own)
    rng = np.random.default_rng(5)
    est = track.cam_xy[None] + rng.normal(0, sigma, (R, K, 2))
    return models, track, est, sample_localization(est, sigma, n_x, rng)


def test_registry_path_equals_the_literal_equations():
    models, track, est, smp = _case()
    args = (models.X, models.Y, models.mean, models.amplitude, models.length_scale, models.noise)
    out = E.fuse_track(models, track, est, smp, var_floor=1e-6, attribution=True)
    assert tuple(out) == BUILTIN[:3] + labels.ATTRIBUTION + ("view_independent",)
    mean_drop = track.dropout.mean(axis=1, keepdims=True)
    sb = np.cumprod(track.own.mean(axis=1), axis=0)
    sb /= sb.sum(axis=1, keepdims=True)
    for r in range(len(est)):
        want = {"with_uncertainty": literal_uncertainty(*args, track.inputs(smp[r]), track.dropout),
                "model_based": literal_model_based(*args, track.inputs(est[r]), track.measurement),
                "simple_bayes": sb,
                labels.WU_POSES_ONLY: literal_uncertainty(*args, track.inputs(smp[r]), mean_drop),
                labels.WU_DROPOUT_ONLY: literal_uncertainty(*args, track.inputs(est[r])[None], track.dropout),
                "view_independent": literal_view_independent(models.Y, track.dropout)}
        for m, p in want.items():
            np.testing.assert_allclose(np.exp(out[m][r]), p, atol=1e-9, err_msg=m)


def test_a_pose_free_method_given_once_is_repeated_not_refused():
    models, track, est, smp = _case()
    fixed, _ = E.pose_free(E.track_input(models, track, var_floor=1e-6))
    assert set(fixed) == {"simple_bayes", "view_independent"}
    a = E.fuse_track(models, track, est, smp, var_floor=1e-6)
    b = E.fuse_track(models, track, est, smp, var_floor=1e-6, fixed=fixed)
    for m in a:
        np.testing.assert_array_equal(a[m], b[m])


@pytest.mark.parametrize("attrs, words", [({"key": "a-b"}, "without '-'"), ({"key": ""}, "non-empty"),
                                          ({"needs": frozenset({"lidar"})}, "unknown needs")])
def test_register_refuses_a_bad_declaration(attrs, words):
    cls = type("Bad", (ToyTempered,), attrs)
    with pytest.raises(ValueError, match=words):
        registry.register(cls)


def test_a_key_registered_twice_is_an_error(toy_method):
    with pytest.raises(ValueError, match="registered twice"):
        registry.register(type("Other", (ToyTempered,), {}))


def test_a_toy_method_reaches_the_fusion_the_labels_and_the_simulation(toy_method):
    models, track, est, smp = _case()
    out = E.fuse_track(models, track, est, smp, var_floor=1e-6)
    assert list(out)[-1] == KEY and out[KEY].shape == out["with_uncertainty"].shape
    np.testing.assert_array_equal(out[KEY][0], out[KEY][1])        # pose-free: one posterior, repeated
    assert KEY in E.single_view_first(models, track, truth=1)
    assert (labels.comparisons()[-1], labels.method_label(KEY, short=True)) == (("with_uncertainty", KEY), "Toy tempered")
    assert labels.ordered_methods({KEY, "dirichlet"}) == ["dirichlet", KEY]
    assert S.methods()[-1] == KEY


def test_without_what_it_needs_a_method_is_skipped():
    models, track, est, smp = _case()
    bare = E.TrackData(track.images, track.cam_xy, track.obj_xy, track.yaw, track.dropout)
    assert "simple_bayes" not in E.fuse_track(models, bare, est, smp, var_floor=1e-6)


@pytest.mark.plugins
def test_entry_points_of_the_group_are_loaded_on_first_use(monkeypatch):
    """A package of one's own registers through the entry-point group (loaded once, in every
    process that asks the registry)."""
    import importlib.metadata

    loaded = []

    class EP:
        name, value = "toy", "tests.support.toy_method:ToyTempered"

        def load(self):
            loaded.append(True)
            return registry.register(ToyTempered)

    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group=None: [EP()] if group == registry.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(registry.registered(), "_loaded", False)
    monkeypatch.setattr(registry.registered(), "_eps_loaded", False)
    try:
        assert KEY in registry.keys() and loaded == [True]
        registry.keys()
        assert loaded == [True]
    finally:
        registry.unregister(KEY)
