"""Scores given the weights do not depend on torch's thread count: the features stage's outputs on
a machine with 1 or 2 threads (or another core count) are the same for the same weights. What does
move across processors is training (the weights themselves): docs/results.md, "Which machine"."""
from __future__ import annotations

import numpy as np
import torch


def test_mc_dropout_scores_are_identical_at_1_and_2_threads():
    from pipeline.scoring.alexnet import build_alexnet, init_for_training
    from pipeline.scoring.features import CropBatch, ScoringModel, forget_scorers, score_batch
    from pipeline.scoring.mc_dropout import crop_seed

    net = init_for_training(build_alexnet(12, 0.5), 0)
    weights = {k: v.detach().numpy() for k, v in net.state_dict().items()}
    crops = np.random.default_rng(0).integers(0, 256, (6, 64, 64, 3), dtype=np.uint8)
    seeds = [crop_seed(0, f"crop{i}") for i in range(len(crops))]
    before = torch.get_num_threads()
    out = {}
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            forget_scorers()   # a fresh scorer per thread count: nothing cached between them
            sm = ScoringModel("thread-test", 12, 0.5, (0.485, 0.456, 0.406), (0.229, 0.224, 0.225), "cpu", weights)
            out[threads] = score_batch(sm, CropBatch("test", 0, crops, seeds, 5))
    finally:
        torch.set_num_threads(before)
        forget_scorers()
    (det1, mc1), (det2, mc2) = out[1], out[2]
    assert mc1.shape == (6, 5, 12) and np.ptp(mc1, axis=1).max() > 0   # dropout does vary the passes
    np.testing.assert_array_equal(det1, det2)
    np.testing.assert_array_equal(mc1, mc2)


def test_scoring_threads_take_the_free_cores_and_at_least_one():
    from pipeline.infra.device import free_of, runnable_others

    assert free_of(2, 0.0) == 2          # an idle machine: every core
    assert free_of(2, 0.4) == 2
    assert free_of(2, 1.0) == 1          # one other busy thread leaves one core
    assert free_of(2, 7.0) == 1          # overloaded: still one thread, never zero
    assert free_of(16, 3.0) == 13
    assert runnable_others(samples=2, gap_s=0.0) >= 0.0
