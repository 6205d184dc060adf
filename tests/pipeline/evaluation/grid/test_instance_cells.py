"""A population cell with the instance term's models (its provider, ``models.instance_term``): the
two instance methods join the cell's posteriors and difficulty, equal to With Uncertainty and Model
Based bit for bit when no class has an instance term, and the other methods' posteriors do not move;
under a test-domain variance they are With Uncertainty and Model Based on the instance models under
that variance; and ``build_cells`` hands the models to the variants that share the default bank only."""
import dataclasses

import numpy as np

from pipeline.evaluation.grid import population as P
from pipeline.infra.config import EvaluateConfig
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.methods.instance_term import INSTANCE_TERM, InstanceBank
from pipeline.method.names import MB_INSTANCE, MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE
from tests.pipeline.evaluation.grid.test_experiments import ring_models
from tests.pipeline.evaluation.grid.test_population import CX, FX, scene
from tests.pipeline.method.test_registry_bit_identical import _cell


def _instance_bank(models, b):
    """``models`` with two training instances per class (alternate views) and amplitude b."""
    labels = [np.arange(len(x)) % 2 for x in models.X]
    shape = models.amplitude.shape
    return InstanceGPClassModels.from_plain(models, labels, np.full(shape, b), np.full(shape, 2.0))


def _with(cell, inst):
    return dataclasses.replace(cell, models={**cell.models, INSTANCE_TERM: inst.subset(cell.classes, cell.components)})


def test_cells_fuse_the_instance_methods():
    cell = _cell(0)
    models = ring_models(C=3, F=2)
    plain = P.run_cell({"default": models}, cell)
    for b, equal in ((0.0, True), (0.01, False)):
        got = P.run_cell({"default": models}, _with(cell, _instance_bank(models, b)))
        for key, per in got["posts"].items():
            assert list(per)[:len(plain["posts"][key])] == list(plain["posts"][key])
            for m, p in plain["posts"][key].items():
                assert np.array_equal(per[m], p), (key, m)     # the other methods untouched
            for new, old in ((WU_INSTANCE, WITH_UNCERTAINTY), (MB_INSTANCE, MODEL_BASED)):
                assert np.array_equal(per[new], per[old]) == equal, (key, new, b)
        assert got["difficulty"][WU_INSTANCE] is not None and MB_INSTANCE in got["difficulty"]
        if equal:
            assert got["difficulty"][WU_INSTANCE] == got["difficulty"][WITH_UNCERTAINTY]
    assert WU_INSTANCE not in plain["difficulty"]


def test_the_instance_methods_follow_the_cells_test_domain_variance():
    """With the instance models as the cell's bank, With Uncertainty and Model Based are the instance
    methods bit for bit, the test-domain variance applied to both routes."""
    cell = dataclasses.replace(_cell(1), test_variance=(0.02, 0.05))
    models = ring_models(C=3, F=2)
    inst = _instance_bank(models, 0.01)
    got = P.run_cell({"default": models}, _with(cell, inst))
    want = P.run_cell({"default": inst}, cell)
    untempered = P.run_cell({"default": models}, _with(dataclasses.replace(cell, test_variance=None), inst))
    for key, per in got["posts"].items():
        for new, old in ((WU_INSTANCE, WITH_UNCERTAINTY), (MB_INSTANCE, MODEL_BASED)):
            assert np.array_equal(per[new], want["posts"][key][old]), (key, new)
            assert not np.allclose(per[new], untempered["posts"][key][new])
    assert got["difficulty"][WU_INSTANCE] == want["difficulty"][WITH_UNCERTAINTY]


def test_only_the_variants_on_the_default_bank_get_the_instance_models():
    df, scores = scene(D=6)
    ev = dataclasses.replace(EvaluateConfig(), targets=("t",), tracks_per_target=2, track_length=4,
                             yaw_source="config", experiments=("biased",))
    plan = {"t": {"classes": ["t", "u"], "components": [0, 1]}}
    index = {"candidate_sets": plan, "own_components": {"t": 0, "u": 1}}
    indexes = {P.DEFAULT: index, "evaluate.variance_floor=0.001": index,          # the default bank shared
               "models.noise_floor=dropout": {"candidate_sets": plan, "own_components": {"t": 0, "u": 1}}}
    ring = ring_models(C=2, F=2)
    ones = np.ones((2, 2))
    inst = _instance_bank(GPClassModels(["t", "u"], [0, 1], ring.X, ring.Y, 0.5 * ones, 0.08 * ones, 0.7 * ones,
                                        1e-3 * ones), 0.01)
    cells, _, _ = P.build_cells(ev, df, scores, indexes, None, {"s1": (FX, CX), "s2": (FX, CX)},
                                {"s1": 0.3, "s2": 0.3}, {INSTANCE_TERM: InstanceBank(inst, plan)})
    by = {}
    for c in cells:
        by.setdefault(c.variant, []).append(c)
    assert len(by) == 3 and all(len(v) == 2 for v in by.values())
    for v, cs in by.items():
        for c in cs:
            assert (INSTANCE_TERM in c.models) == (v != "models.noise_floor=dropout"), v
            if INSTANCE_TERM in c.models:
                assert c.models[INSTANCE_TERM].classes == ["t", "u"] and c.models[INSTANCE_TERM].components == [0, 1]
