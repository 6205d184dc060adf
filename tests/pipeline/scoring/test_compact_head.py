"""The early epochs' compact AlexNet head and crops: the compact head is the full network with its
first Dropout off, in values and in gradients, at a fraction of the first Linear layer's work."""
import copy

import numpy as np
import pytest
import torch

from pipeline.scoring.alexnet import build_alexnet, compact_forward, init_for_training
from pipeline.scoring.training import crop
from tests.support.float_tolerance import rounding_tol


def _net(seed: int = 0):
    return init_for_training(build_alexnet(12, 0.5), seed)


def _full_without_first_dropout(model, x):
    head = model.classifier
    return head[1:](torch.flatten(model.avgpool(model.features(x)), 1))


@pytest.mark.parametrize("side", [64, 80, 112, 160])   # trunk maps 1x1, 1x1, 3x3, 4x4 (not a repeat)
def test_compact_head_equals_the_full_head_without_its_first_dropout(side):
    model = _net().eval()
    x = torch.randn(3, 3, side, side, generator=torch.Generator().manual_seed(side))
    with torch.no_grad():
        ref = _full_without_first_dropout(model, x)
        got = compact_forward(model, x)
        ref64 = _full_without_first_dropout(copy.deepcopy(model).double(), x.double())
    assert got.shape == ref.shape == (3, 12)
    # another summation order of the first Linear layer: float32 rounding apart, read off the full
    # head's own error against its float64 evaluation (tests/support/float_tolerance.py)
    torch.testing.assert_close(got, ref, rtol=0, atol=rounding_tol(ref, ref64))


def test_compact_head_gives_every_weight_the_full_heads_gradient():
    """Training through the compact head moves the same weights as the full one would: the first
    Linear layer's gradient arrives at all 36 copies of a column (and at the trunk) unchanged."""
    x = torch.randn(4, 3, 80, 80, generator=torch.Generator().manual_seed(1))
    y = torch.tensor([0, 3, 7, 11])
    grads = []
    for fwd in (_full_without_first_dropout, compact_forward):
        model = _net(2).eval()   # eval: the second Dropout off too, so both see the same network
        torch.nn.functional.cross_entropy(fwd(model, x), y).backward()
        grads.append({k: p.grad.clone() for k, p in model.named_parameters()})
    for k in grads[0]:
        scale = float(grads[0][k].abs().max()) or 1.0
        assert torch.allclose(grads[1][k], grads[0][k], rtol=1e-4, atol=1e-5 * scale), k
    # the copies of one column got one gradient: all 36 positions of channel 5 alike
    g = grads[1]["classifier.1.weight"].view(4096, 256, 36)[:, 5, :]
    assert torch.allclose(g, g[:, :1].expand_as(g))


def test_compact_head_keeps_the_second_dropout_in_training():
    model = _net().train()
    x = torch.randn(2, 3, 80, 80, generator=torch.Generator().manual_seed(3))
    torch.manual_seed(0)
    a = compact_forward(model, x)
    b = compact_forward(model, x)
    assert not torch.allclose(a, b)       # the second Dropout draws new masks
    model.classifier[3].p = 0.0
    assert torch.allclose(compact_forward(model, x), compact_forward(model, x))


def test_crop_cuts_one_random_square_at_the_same_place_in_every_image():
    x = torch.arange(2 * 3 * 10 * 12, dtype=torch.float32).view(2, 3, 10, 12)
    x = x.contiguous(memory_format=torch.channels_last)
    seen = set()
    for s in range(20):
        y = crop(x, 6, np.random.default_rng(s))
        assert y.shape == (2, 3, 6, 6) and y.is_contiguous(memory_format=torch.channels_last)
        top, left = divmod(int(y[0, 0, 0, 0]), 12)
        assert torch.equal(y, x[:, :, top:top + 6, left:left + 6])
        assert 0 <= top <= 4 and 0 <= left <= 6
        seen.add((top, left))
    assert len(seen) > 5                      # the place is drawn, not fixed
    assert crop(x[..., :10], 10, np.random.default_rng(0)).shape[-1] == 10
    with pytest.raises(ValueError, match="exceeds"):
        crop(x, 11, np.random.default_rng(0))
