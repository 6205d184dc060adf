"""The scoring route's speed-ups (trunk in channels-last, inference mode) leave the scores equal to
the plain route's (contiguous NCHW, no_grad as before) to float32 rounding (``rounding_tol``: four
times the plain route's own error against its float64 evaluation, ~1e-6) for the networks whose
registry entry scores in channels-last (AlexNet); EfficientNet-Lite0's depthwise kernels move them
by ~3e-6, so it keeps the contiguous route (the measured difference is asserted, so a change shows)."""
import copy

import numpy as np
import pytest
import torch

from pipeline.scoring.crops import to_tensor
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
from tests.support.float_tolerance import rounding_tol


def _float64_scores(net, x, seeds, n):
    """The plain route in float64 (torch's own Linear: oneDNN's packed layers are float32 only)."""
    return MCDropoutScorer(copy.deepcopy(net).double(), onednn=False).score(x.double(), seeds, n)


def _randomised(net):
    """Weights drawn at fan-in scale (a fresh EfficientNet's head is zero: every score equal)."""
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for p in net.parameters():
            fan_in = p[0].numel() if p.dim() > 1 else 1
            p.copy_(torch.randn(p.shape, generator=g) * (2.0 / fan_in) ** 0.5 if p.dim() > 1 else
                    1 + 0.1 * torch.randn(p.shape, generator=g))
    return net


def _nets():
    from pipeline.scoring.alexnet import build_alexnet, init_for_training
    from pipeline.scoring.classifiers import classifier

    torch.manual_seed(0)
    eff = classifier("efficientnet_lite0")
    yield "alexnet", init_for_training(build_alexnet(7, 0.5), 0), 64
    yield "efficientnet_lite0", _randomised(eff.build(7, 0.2, 0.0)), 64
    yield "efficientnet_lite0 drop-connect", _randomised(eff.build(7, 0.2, 0.2)), 64


@pytest.mark.parametrize("name,net,size", list(_nets()), ids=lambda v: v if isinstance(v, str) else "")
def test_channels_last_scores_equal_the_plain_route_where_the_registry_uses_it(name, net, size):
    from pipeline.scoring.classifiers import classifier

    derived = classifier(name.split()[0]).channels_last_scoring
    rng = np.random.default_rng(1)
    crops = rng.integers(0, 256, (5, size, size, 3), dtype=np.uint8)
    x = to_tensor(crops)
    seeds = [crop_seed(0, f"{name}/{i}") for i in range(len(crops))]
    old = MCDropoutScorer(copy.deepcopy(net), channels_last=False)
    new = MCDropoutScorer(copy.deepcopy(net), channels_last=True)
    assert new.model.features[0].weight.is_contiguous(memory_format=torch.channels_last) if name == "alexnet" else True
    det0, mc0 = old.score(x, seeds, 4)
    det1, mc1 = new.score(x, seeds, 4)
    if derived:
        det64, mc64 = _float64_scores(net, x, seeds, 4)
        tol = max(rounding_tol(det0, det64), rounding_tol(mc0, mc64))
    else:
        tol = 1e-4
    assert mc0.shape == (5, 4, 7) and float(mc0.std(dim=1).max()) > 0   # the samples do differ
    assert float((det0 - det1).abs().max()) <= tol
    assert float((mc0 - mc1).abs().max()) <= tol
    # and the deterministic pass is the network's own eval-mode forward
    with torch.no_grad():
        plain = torch.softmax(copy.deepcopy(net).eval()(x), -1)
    assert float((plain - det0).abs().max()) <= tol
    assert float((plain - det1).abs().max()) <= tol


def test_the_executor_task_scores_like_the_plain_route():
    """``score_batch`` (what the stage's executor runs) against the contiguous no_grad route."""
    from pipeline.scoring.alexnet import build_alexnet, init_for_training
    from pipeline.scoring.features import CropBatch, ScoringModel, forget_scorers, score_batch

    net = init_for_training(build_alexnet(5, 0.5), 2)
    crops = np.random.default_rng(4).integers(0, 256, (6, 64, 64, 3), dtype=np.uint8)
    seeds = [crop_seed(1, f"c{i}") for i in range(len(crops))]
    mean, std = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
    x = to_tensor(crops, mean, std)
    det0, mc0 = MCDropoutScorer(copy.deepcopy(net), channels_last=False).score(x, seeds, 3)
    det64, mc64 = _float64_scores(net, x, seeds, 3)
    sm = ScoringModel("route-test", 5, 0.5, mean, std, "cpu", {k: v.numpy() for k, v in net.state_dict().items()})
    try:
        det1, mc1 = score_batch(sm, CropBatch("test", 0, crops, seeds, 3))
    finally:
        forget_scorers()
    np.testing.assert_allclose(det1, det0.numpy(), rtol=0, atol=rounding_tol(det0, det64))
    np.testing.assert_allclose(mc1, mc0.numpy(), rtol=0, atol=rounding_tol(mc0, mc64))


@pytest.mark.parametrize("size", [160, 97])
def test_efficientnet_scoring_path_equals_the_training_forward(size):
    """Without gradients EfficientNet-Lite0 pads evenly-padded convolutions inside the convolution
    and applies ReLU6 in place; its scores equal the graph-building forward's (explicit F.pad, ReLU6
    copies) to float32 rounding (``rounding_tol``), at an even and an odd input size (odd sizes pad asymmetrically after stride 2)."""
    from pipeline.scoring.classifiers import classifier

    net = _randomised(classifier("efficientnet_lite0").build(7, 0.2, 0.0)).eval()
    x = to_tensor(np.random.default_rng(5).integers(0, 256, (3, size, size, 3), dtype=np.uint8))
    with torch.enable_grad():
        slow = torch.softmax(net(x.requires_grad_(True)), -1).detach()
    with torch.inference_mode():
        fast = torch.softmax(net(x.detach()), -1)
    with torch.no_grad():
        exact = torch.softmax(copy.deepcopy(net).double()(x.detach().double()), -1)
    assert float(slow.std(dim=0).max()) > 1e-3          # the crops do score differently
    assert float((slow - fast).abs().max()) <= rounding_tol(slow, exact)


@pytest.mark.parametrize("name,net,size", list(_nets())[:2], ids=lambda v: v if isinstance(v, str) else "")
def test_trunk_in_chunks_scores_like_one_call(name, net, size):
    """The scorer runs the trunk TRUNK_CHUNK images at a time, the last call taking the remainder
    (memory, not results): a batch of 2 chunks and 3 scores as one trunk call on it does, to float32
    rounding (``rounding_tol``)."""
    from pipeline.scoring.mc_dropout import TRUNK_CHUNK

    crops = np.random.default_rng(6).integers(0, 256, (2 * TRUNK_CHUNK + 3, size, size, 3), dtype=np.uint8)
    x = to_tensor(crops)
    seeds = [crop_seed(0, f"chunk/{i}") for i in range(len(crops))]
    sc = MCDropoutScorer(copy.deepcopy(net))
    before = torch.get_num_threads()
    torch.set_num_threads(1)   # one thread: where oneDNN picks a batch-size-dependent path
    try:
        det, mc = sc.score(x, seeds, 3)
        with torch.inference_mode():
            whole = sc._trunk(sc._input(x))
            det1 = torch.softmax(sc.head_eval(whole), -1)
            mc1 = torch.softmax(sc.head_samples(whole, sc.draw_masks(seeds, 3)), -1)
    finally:
        torch.set_num_threads(before)
    # the rounding error's scale read on 4 of the crops (same route, same law per crop): float64
    # EfficientNet on all 35 costs more than the rest of the test
    det64, mc64 = _float64_scores(net, x[:4], seeds[:4], 3)
    assert float((det - det1).abs().max()) <= rounding_tol(det1[:4], det64)
    assert float((mc - mc1).abs().max()) <= rounding_tol(mc1[:4], mc64)
