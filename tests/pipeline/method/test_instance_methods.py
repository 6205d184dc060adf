"""The two registered methods with the instance term: on one instance per class (COIL) they are
With Uncertainty and Model Based bit for bit, fit included; with several instances they differ; a
cell without the instance models (their provider's) skips them."""
import numpy as np
import pytest

from pipeline.method import registry
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_instance_fit import fit_instance_models
from pipeline.method.methods.instance_term import INSTANCE_TERM
from pipeline.method.names import MB_INSTANCE, MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE
from tests.pipeline.method.test_gp_instance_fit import hierarchical

PAIRS = ((WU_INSTANCE, WITH_UNCERTAINTY), (MB_INSTANCE, MODEL_BASED))


def banks(n_inst, seed=0, C=3, F=2):
    """Plain and instance banks fitted on the same generated rings (C classes, F components)."""
    rng = np.random.default_rng(seed)
    X, Y, labels = [], [], []
    for c in range(C):
        Yc = []
        for f in range(F):
            x, y, lab = hierarchical(rng, n_inst=n_inst, n_views=12, m=0.2 + 0.1 * c + 0.05 * f)
            Yc.append(y)
        X.append(x)
        Y.append(np.stack(Yc))
        labels.append([f"obj{c}_{i}" for i in lab])
    kw = dict(restarts=1, progress=False)
    names = [f"k{c}" for c in range(C)]
    plain, _ = fit_class_models(X, Y, names, list(range(F)), **kw)
    inst, diags = fit_instance_models(X, Y, labels, names, list(range(F)), **kw)
    return plain, inst, diags


def track_input(plain, inst, seed=1, K=4, R=2, n_x=3, n_s=5):
    rng = np.random.default_rng(seed)
    est = np.c_[np.cos(np.linspace(0, 1.5, K)), np.sin(np.linspace(0, 1.5, K))][None] * 2.0
    est = est + 0.05 * rng.standard_normal((R, K, 2))
    dropout = 0.3 + 0.05 * rng.standard_normal((K, n_s, plain.n_components))
    return registry.TrackInput(dropout=dropout, gp=plain, models={} if inst is None else {INSTANCE_TERM: inst},
                               estimates=est,
                               samples=sample_localization(est, 0.1, n_x, rng),
                               inputs=lambda p: relative_inputs(p, np.zeros(2), 0.0, unit_circle=True))


def test_one_instance_per_class_equals_the_plain_methods_bit_for_bit():
    plain, inst, diags = banks(n_inst=1)
    assert not np.any(inst.instance_amplitude) and all(not d["instance_term"] for d in diags)
    t = track_input(plain, inst)
    for new, old in PAIRS:
        a, b = registry.get(new), registry.get(old)
        assert a.applies(t)
        assert np.array_equal(a.fuse(t), b.fuse(t)), new
        assert np.array_equal(a.single_view(t), b.single_view(t)), new


def test_several_instances_change_the_posterior_and_no_bank_skips():
    plain, inst, diags = banks(n_inst=4)
    assert np.all(inst.instance_amplitude > 0) and all(d["instance_term"] for d in diags)
    t = track_input(plain, inst)
    for new, old in PAIRS:
        got = registry.get(new).fuse(t)
        assert np.all(np.isfinite(got)) and np.max(np.abs(got - registry.get(old).fuse(t))) > 1e-6
    bare = track_input(plain, None)
    assert not any(registry.get(new).applies(bare) for new, _ in PAIRS)


@pytest.mark.parametrize("key", [WU_INSTANCE, MB_INSTANCE])
def test_registered_after_the_plain_methods(key):
    keys = registry.keys()
    assert key in keys and keys.index(key) > keys.index(WITH_UNCERTAINTY)


def test_public_fit_models_takes_instance_labels():
    import viewfuse as vf

    rng = np.random.default_rng(2)
    x1, y1, lab1 = hierarchical(rng, n_inst=3, n_views=8)
    x2, y2, _ = hierarchical(rng, n_inst=1, n_views=8)
    samples = {"a": (np.arctan2(x1[:, 1], x1[:, 0]), y1[:, None]), "b": (np.arctan2(x2[:, 1], x2[:, 0]), y2[:, None])}
    models = vf.fit_models(samples, restarts=0, instances={"a": lab1})
    assert [d["instance_term"] for d in models.diagnostics] == [True, False]
    plain = vf.fit_models(samples, restarts=0)
    assert models.amplitude[1, 0] == plain.amplitude[1, 0]
    cams = 2.0 * np.c_[np.cos([0.1, 0.4]), np.sin([0.1, 0.4])]
    drop = 0.3 + 0.01 * rng.standard_normal((2, 3, 1))
    assert vf.fuse("with_uncertainty_instance", models, cameras=cams, dropout=drop).shape == (2, 2)
    with pytest.raises(ValueError, match="needs"):
        vf.fuse("with_uncertainty_instance", plain, cameras=cams, dropout=drop)
    with pytest.raises(ValueError, match="instances name class 'zzz'"):
        vf.fit_models(samples, restarts=0, instances={"zzz": lab1})
