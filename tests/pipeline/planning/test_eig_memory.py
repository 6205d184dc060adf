"""The information gain's Monte-Carlo draws are processed in chunks: the result does not depend on
the chunk size, and the peak memory stays flat as ``plan.eig_samples`` grows."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from pipeline.planning import eig
from pipeline.planning.eig import expected_information_gain, standard_draws
from tests.pipeline.planning.ring import models


def _inputs(V: int, N: int) -> np.ndarray:
    th = np.random.default_rng(0).uniform(0, 2 * np.pi, (V, N))
    return np.stack([np.cos(th), np.sin(th)], -1)


@pytest.mark.parametrize("chunk_bytes", [1, 4000, 10 ** 6])
def test_chunked_gain_equals_one_pass(monkeypatch, chunk_bytes):
    m = models()
    x, lp0, eps = _inputs(3, 5), np.log([0.4, 0.6]), standard_draws(1001, 1, 2)  # M not a multiple of N
    whole, se_whole = expected_information_gain(m, x, lp0, eps, return_se=True)
    monkeypatch.setattr(eig, "CHUNK_BYTES", chunk_bytes)
    parts, se_parts = expected_information_gain(m, x, lp0, eps, return_se=True)
    np.testing.assert_allclose(parts, whole, rtol=0, atol=1e-12)
    np.testing.assert_allclose(se_parts, se_whole, rtol=0, atol=1e-12)


def _peak(M: int) -> int:
    m, x, lp0 = models(), _inputs(6, 40), np.log([0.4, 0.6])
    eps = standard_draws(M, 1, 0)
    tracemalloc.start()
    expected_information_gain(m, x, lp0, eps)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def test_peak_memory_stays_flat_as_the_draws_grow(monkeypatch):
    monkeypatch.setattr(eig, "CHUNK_BYTES", 4 * 2 ** 20)
    small, large = _peak(2_000), _peak(40_000)
    # unchunked, the 38 000 extra draws would add ~5 x 6*2*40*2*8 bytes each (~150 MB here)
    assert large < small + 8 * 2 ** 20, (small, large)
