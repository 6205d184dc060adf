"""MC dropout: trunk once + batched head == N_s full stochastic passes (exactly, and in distribution)."""
import copy

import numpy as np
import pytest
import torch
from scipy import stats

from typing import Sequence

from torch import nn

from pipeline.scoring.alexnet import build_alexnet, init_for_training
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
from tests.support.float_tolerance import rounding_tol


class FixedMaskDropout(nn.Module):
    """Dropout with a given mask (0 or 1/(1-p) entries): the literal reference route."""

    def __init__(self, mask: torch.Tensor):
        super().__init__()
        self.mask = mask

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.mask


@torch.no_grad()
def full_passes_with_masks(model: nn.Module, x: torch.Tensor, masks: Sequence[torch.Tensor]) -> torch.Tensor:
    """Logits (B, N_s, D) from ``N_s`` complete forward passes per crop (trunk included), with the
    Dropout layers replaced by fixed-mask modules: the literal definition MC dropout must match."""
    B, n = masks[0].shape[:2]
    xr = x.repeat_interleave(n, dim=0)  # row b*n + s = crop b, sample s
    layers, k = [], 0
    for m in model.classifier:
        if isinstance(m, nn.Dropout):
            layers.append(FixedMaskDropout(masks[k].reshape(B * n, -1)))
            k += 1
        else:
            layers.append(m)
    head = nn.Sequential(*layers)
    f = torch.flatten(model.avgpool(model.features(xr)), 1)
    return head(f).reshape(B, n, -1)


SIZE = 64  # tiny crops: AlexNet pools adaptively, so the head is the same size as at 224


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return init_for_training(build_alexnet(5, dropout=0.5), seed=3).eval()


@pytest.fixture(scope="module")
def crops():
    return torch.randn(3, 3, SIZE, SIZE, generator=torch.Generator().manual_seed(1))


@pytest.fixture(scope="module")
def tol(model, crops):
    """Float32 rounding of the scorer's scores (tests/support/float_tolerance.py): its own error
    against the same route in float64. Two float32 routes that differ only in the order of their
    operations (batch size, head grouping, oneDNN against torch's Linear) agree to this, on any
    processor; a fixed 1e-6 sits at one machine's rounding noise."""
    seeds = [crop_seed(0, f"c{i}") for i in range(3)]
    det, mc = MCDropoutScorer(model, onednn=False).score(crops, seeds, n_samples=5)
    det64, mc64 = MCDropoutScorer(copy.deepcopy(model).double(), onednn=False).score(crops.double(), seeds, 5)
    return max(rounding_tol(det, det64), rounding_tol(mc, mc64))


def test_batched_head_equals_full_passes_with_the_same_masks(model, crops):
    sc = MCDropoutScorer(model)
    masks = sc.draw_masks([crop_seed(0, f"c{i}") for i in range(3)], n_samples=4)
    fast = sc.head_samples(sc.trunk(crops), masks)
    slow = full_passes_with_masks(model, crops, masks)
    assert fast.shape == slow.shape == (3, 4, 5)
    # logits to float32 rounding: the literal route's own error against its float64 evaluation
    slow64 = full_passes_with_masks(copy.deepcopy(model).double(), crops.double(), [m.double() for m in masks])
    torch.testing.assert_close(fast, slow, rtol=0, atol=rounding_tol(slow, slow64))
    # The samples really differ from each other and from the deterministic pass.
    det = sc.head_eval(sc.trunk(crops))
    assert (fast - det[:, None]).abs().amax() > 1e-3
    assert (fast[:, 0] - fast[:, 1]).abs().amax() > 1e-3


def test_masks_are_scaled_bernoulli_and_seeded_per_crop(model):
    sc = MCDropoutScorer(model)
    assert sc.p == [0.5, 0.5] and sc.dropout_dims == [9216, 4096]
    seeds = [crop_seed(7, "a"), crop_seed(7, "b")]
    m1, m2 = sc.draw_masks(seeds, 6)
    assert m1.shape == (2, 6, 9216) and m2.shape == (2, 6, 4096)
    vals = torch.unique(torch.cat([m1.flatten(), m2.flatten()]))
    torch.testing.assert_close(vals, torch.tensor([0.0, 2.0]))
    keep = float((m1 > 0).float().mean())
    n = m1.numel()
    assert abs(keep - 0.5) < 4 * np.sqrt(0.25 / n)          # Bernoulli(1 - p) rate
    # Same (seed, key) -> same masks whatever the batch; different keys -> independent masks.
    a1, a2 = sc.draw_masks(seeds[1:], 6)
    torch.testing.assert_close(a1[0], m1[1])
    torch.testing.assert_close(a2[0], m2[1])
    agree = float(((m1[0] > 0) == (m1[1] > 0)).float().mean())
    assert abs(agree - 0.5) < 0.01
    assert crop_seed(0, "x") != crop_seed(1, "x") and crop_seed(0, "x") == crop_seed(0, "x")


def test_scores_do_not_depend_on_the_batch(model, crops, tol):
    sc = MCDropoutScorer(model)
    seeds = [crop_seed(0, f"c{i}") for i in range(3)]
    det, mc = sc.score(crops, seeds, n_samples=5)
    det2, mc2 = sc.score(crops[2:], seeds[2:], n_samples=5)
    torch.testing.assert_close(mc[2], mc2[0], rtol=0, atol=tol)   # another batch: another kernel order
    torch.testing.assert_close(det[2], det2[0], rtol=0, atol=tol)
    torch.testing.assert_close(mc.sum(-1), torch.ones(3, 5))
    # Deterministic pass = the model in eval mode.
    torch.testing.assert_close(det, torch.softmax(model.eval()(crops), -1), rtol=0, atol=tol)
    with pytest.raises(ValueError, match="seed"):
        sc.score(crops, seeds[:2], n_samples=5)


def test_no_dropout_gives_the_deterministic_pass(crops):
    m = init_for_training(build_alexnet(4, dropout=0.0), seed=0).eval()
    sc = MCDropoutScorer(m)
    det, mc = sc.score(crops, [1, 2, 3], n_samples=3)
    # the head runs on B x N_s rows against B: another GEMM shape, so float32 rounding apart
    det64, _ = MCDropoutScorer(copy.deepcopy(m).double(), onednn=False).score(crops.double(), [1, 2, 3], 1)
    torch.testing.assert_close(mc, det[:, None].expand_as(mc), rtol=0, atol=rounding_tol(det, det64))


def test_same_distribution_as_torch_dropout_in_train_mode(model, crops):
    """Statistical check against the real thing: nn.Dropout's own RNG, full network passes."""
    n = 400
    x = crops[:1]
    sc = MCDropoutScorer(model)
    ours = sc.head_samples(sc.trunk(x), sc.draw_masks([crop_seed(0, "stat")], n))[0]      # (n, 5)
    torch.manual_seed(123)
    model.train()
    try:
        with torch.no_grad():
            ref = model(x.expand(n, -1, -1, -1).contiguous())                              # (n, 5)
    finally:
        model.eval()
    for k in range(ours.shape[1]):
        a, b = ours[:, k].numpy(), ref[:, k].numpy()
        assert stats.ks_2samp(a, b).pvalue > 1e-3, k
        # and the spread is real (not two identical constants)
        assert a.std() > 1e-3
    # A wrong route (dropout p doubled) is detected by the same test.
    wrong = ((sc.draw_masks([crop_seed(1, "w")], n)[0] > 0) & (torch.rand(1, n, 9216) < 0.5)).float() * 4.0
    bad = sc.head_samples(sc.trunk(x), [wrong, sc.draw_masks([crop_seed(2, "w")], n)[1]])[0]
    assert min(stats.ks_2samp(bad[:, k].numpy(), ref[:, k].numpy()).pvalue for k in range(5)) < 1e-3


def test_onednn_head_matches_the_plain_linear_head(model, crops, tol):
    fast, plain = MCDropoutScorer(model, onednn=True), MCDropoutScorer(model, onednn=False)
    assert all(isinstance(m, torch.nn.Linear) for m in plain.head if hasattr(m, "in_features"))
    seeds = [crop_seed(4, f"k{i}") for i in range(3)]
    d1, m1 = fast.score(crops, seeds, 4)
    d2, m2 = plain.score(crops, seeds, 4)
    torch.testing.assert_close(d1, d2, rtol=0, atol=tol)
    torch.testing.assert_close(m1, m2, rtol=0, atol=tol)
