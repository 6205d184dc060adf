"""A population cell with the instance bank (models.instance_term): the two instance methods join
the cell's posteriors and difficulty, equal to With Uncertainty and Model Based bit for bit when no
class has an instance term, and the other methods' posteriors do not move."""
import numpy as np

from pipeline.evaluation.grid import population as P
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.names import MB_INSTANCE, MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE
from tests.pipeline.evaluation.grid.test_experiments import ring_models
from tests.pipeline.method.test_registry_bit_identical import _cell


def _instance_bank(models, b):
    """``models`` with two training instances per class (alternate views) and amplitude b."""
    labels = [np.arange(len(x)) % 2 for x in models.X]
    shape = models.amplitude.shape
    return InstanceGPClassModels.from_plain(models, labels, np.full(shape, b), np.full(shape, 2.0))


def test_cells_fuse_the_instance_methods():
    cell = _cell(0)
    models = ring_models(C=3, F=2)
    plain = P.run_cell({"default": models}, cell)
    for b, equal in ((0.0, True), (0.01, False)):
        got = P.run_cell({"default": models, P.INSTANCE_BANK: _instance_bank(models, b)}, cell)
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
