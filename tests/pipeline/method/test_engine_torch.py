"""The torch float64 engine (pipeline/method/engine_torch.py) equals the numpy engine: on CPU torch
always, on a GPU where CUDA is present."""
import numpy as np
import pytest

from pipeline.method.fusion import engine_device, fuse_model_based, fuse_with_uncertainty
from tests.pipeline.method.test_engine import assert_log_close, random_models, random_tracks

torch = pytest.importorskip("torch")


def both(models, X, Z, device, **kw):
    out = []
    for dev in ("cpu", device):
        with engine_device(dev):
            out.append((fuse_with_uncertainty(models, X, Z, return_log=True, progress=False, **kw),
                        fuse_model_based(models, X[:, 0], Z.mean(2), return_log=True, progress=False)))
    return out


@pytest.mark.parametrize("seed,ell", [(0, (0.3, 1.2)), (1, (0.03, 0.06)), (2, (0.05, 1.5))])
def test_torch_on_cpu_equals_numpy(seed, ell):
    rng = np.random.default_rng(200 + seed)
    models = random_models(rng, 3, 2, ell=ell)     # basis route, exact route, a mix
    X, Z = random_tracks(rng, 3, 6, [1, 5, 9][seed], 4, 2, wrap=seed == 1)
    (a, b), (c, d) = both(models, X, Z, "torch-cpu", prior=[0.2, 0.3, 0.5])
    assert_log_close(c, a)
    assert_log_close(d, b)


def test_torch_off_circle_inputs_take_the_exact_route():
    rng = np.random.default_rng(9)
    models = random_models(rng, 2, 2)
    X, Z = random_tracks(rng, 2, 4, 6, 3, 2, unit=False)
    (a, b), (c, d) = both(models, X, Z, "torch-cpu")
    assert_log_close(c, a)
    assert_log_close(d, b)


def test_unknown_or_missing_device_is_an_error():
    with pytest.raises(ValueError, match="unknown device"):
        with engine_device("tpu"):
            pass
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="no CUDA GPU"):
            with engine_device("cuda"):
                pass


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU")
def test_gpu_equals_numpy():
    rng = np.random.default_rng(31)
    models = random_models(rng, 4, 4, ell=(0.05, 1.5))
    X, Z = random_tracks(rng, 4, 20, 9, 10, 4)
    (a, b), (c, d) = both(models, X, Z, "cuda")
    assert_log_close(c, a)
    assert_log_close(d, b)
