"""The models and evaluate stages' numerics given their inputs do not depend on the thread count:
GP fits under 1 or 2 BLAS threads, and With Uncertainty's fusion with 1 or 2 worker threads, give
identical numbers (what can move across processors is the classifier's training: docs/results.md,
"Which machine")."""
from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline.method.fusion import fuse_with_uncertainty
from pipeline.method.gp_fit import fit_class_models
from tests.pipeline.method.test_engine import random_models, random_tracks


def _ring(n: int) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([np.cos(a), np.sin(a)], 1)


def test_gp_fits_are_identical_under_1_and_2_blas_threads():
    rng = np.random.default_rng(3)
    X = _ring(60)
    Y = [0.3 + 0.05 * rng.standard_normal((2, 60)) + 0.1 * np.sin(np.arange(60) / 9.0) for _ in range(2)]
    fits = {}
    for threads in (1, 2):
        with threadpool_limits(limits=threads):
            fits[threads], _ = fit_class_models([X, X], Y, ["a", "b"], [1, 4], restarts=2, seed=1, progress=False)
    for attr in ("length_scale", "amplitude", "noise", "mean"):
        np.testing.assert_array_equal(getattr(fits[1], attr), getattr(fits[2], attr))


def test_fusion_is_identical_with_1_and_2_threads():
    rng = np.random.default_rng(5)
    models = random_models(rng, 3, 4)
    X, Z = random_tracks(rng, 4, 9, 5, 6, 4)
    one = fuse_with_uncertainty(models, X, Z, return_log=True, threads=1, block=2000, progress=False)
    two = fuse_with_uncertainty(models, X, Z, return_log=True, threads=2, block=2000, progress=False)
    assert np.isfinite(one).all()
    np.testing.assert_array_equal(one, two)
