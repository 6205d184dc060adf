"""MC dropout's head runs on at most HEAD_ROWS (crop, sample) rows at a time, so memory stays flat
as N_s grows, and the grouping of crops does not change their scores."""
from __future__ import annotations

import copy

import torch

from pipeline.scoring import mc_dropout
from pipeline.scoring.alexnet import build_alexnet, init_for_training
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
from tests.support.float_tolerance import rounding_tol


def scorer() -> MCDropoutScorer:
    torch.manual_seed(0)
    return MCDropoutScorer(init_for_training(build_alexnet(5, dropout=0.5), seed=3).eval())


def rows_per_pass(sc: MCDropoutScorer) -> list[int]:
    seen: list[int] = []
    inner = sc.head_samples

    def spy(f, masks):
        seen.append(f.shape[0] * masks[0].shape[1])
        return inner(f, masks)
    sc.head_samples = spy
    return seen


def test_head_passes_stay_within_the_row_cap_and_scores_do_not_change(monkeypatch):
    x = torch.randn(5, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    seeds = [crop_seed(0, f"c{i}") for i in range(5)]
    sc = scorer()
    seen = rows_per_pass(sc)
    det, mc = sc.score(x, seeds, n_samples=4)
    assert seen == [20]  # under the cap: one pass, as before
    monkeypatch.setattr(mc_dropout, "HEAD_ROWS", 8)
    seen.clear()
    det2, mc2 = sc.score(x, seeds, n_samples=4)
    assert seen == [8, 8, 4]  # two crops of 4 samples per pass
    torch.testing.assert_close(det2, det, rtol=0, atol=0)   # the same trunk and eval head: the same bits
    # another head grouping (8 rows against 20): another GEMM shape, so the float32 rounding of the
    # route (its error against float64, read on 2 of the crops) apart, on any processor
    _, mc64 = MCDropoutScorer(copy.deepcopy(sc.model).double(), onednn=False).score(x[:2].double(), seeds[:2], 4)
    torch.testing.assert_close(mc2, mc, rtol=0, atol=rounding_tol(mc[:2], mc64))
    seen.clear()
    sc.score(x[:2], seeds[:2], n_samples=20)  # N_s above the cap: one crop per pass
    assert seen == [20, 20]


def test_the_default_batch_is_one_head_pass():
    from pipeline.infra.config import Config
    f = Config().features
    assert f.batch_size * max(f.n_samples, f.bigbird_samples) <= mc_dropout.HEAD_ROWS
