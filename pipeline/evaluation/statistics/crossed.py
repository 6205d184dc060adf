"""The two-way (crossed) bootstrap of an object x scan design: objects (targets) and scans are
resampled independently (the pigeonhole bootstrap), for populations where the same objects recur
across scans (``evaluate.statistics.cluster = "crossed"``, configs/real_full.toml).

A draw picks the targets with replacement (multiplicity ``m_o``) and, independently, the scans
(``m_s``). A track of target o in scan s weighs ``m_s`` inside its target's mean, and the target
weighs ``m_o`` in the pool over targets, so each (object, scan) cell's tracks count with the
product of the two multiplicities; a target none of whose scans was drawn drops out of that draw.
Tracks are not resampled within a cell: the cells carry that variation. With every multiplicity 1
this is the data's own statistic (the pool over targets of the target means, as the nested
resampler's), so the point value does not depend on the clustering; only the interval does.
Draws are made once per (structure, draws, seed) and shared, like ``resampler.draws``: every
metric, method and paired difference reads the same ones.
"""
from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from pipeline.evaluation.statistics.resampler import estimate


class CrossedResampler:
    """``scan_of`` (T, W): the scan index of each (target, track) slot, -1 where the target has no
    such track. Values come padded as the nested resampler's one-seed layout (1, T, >= W)."""

    def __init__(self, scan_of: np.ndarray, n_boot: int, seed):
        self.scan_of = np.asarray(scan_of, dtype=np.int64)
        T, W = self.scan_of.shape
        self.leaves = self.scan_of >= 0
        if T < 1 or not self.leaves.any(axis=1).all():
            raise ValueError("crossed bootstrap: every target needs a track")
        S = int(self.scan_of.max()) + 1
        self.shape, self.n_boot, self.n_scans = (1, T, W), int(n_boot), S
        rng = np.random.default_rng(seed)
        B = self.n_boot
        self.m_obj = _multiplicities(rng, B, T)                            # (B, T)
        self.m_scan = _multiplicities(rng, B, S)                           # (B, S)
        self._drawn: tuple | None = None

    def spread(self) -> bool:
        return self.shape[1] > 1 or self.n_scans > 1

    def _weights(self, m_obj: np.ndarray, m_scan: np.ndarray):
        """Track weights (..., T, W) inside each target's mean, and each target's weight (..., T)."""
        w = np.where(self.leaves, m_scan[..., np.maximum(self.scan_of, 0)], 0.0)
        return w, np.where(w.sum(axis=-1) > 0, m_obj, 0.0)

    def _prepared(self, m_obj: np.ndarray, m_scan: np.ndarray) -> tuple:
        """What every statistic of these multiplicities shares: (track weights, which are drawn,
        their sums per target, the targets' weights)."""
        w, wt = self._weights(m_obj, m_scan)
        return w, w > 0, w.sum(axis=-1), wt

    def _stat(self, values: np.ndarray, prepared: tuple, pool: str) -> np.ndarray:
        v = np.asarray(values, float)[0, :, : self.shape[2]]                # (T, W)
        w, used, wsum, wt = prepared
        with np.errstate(invalid="ignore", divide="ignore"):
            tm = np.where(used, w * v, 0.0).sum(axis=-1) / wsum               # (..., T)
        nan = np.isnan(v)
        if nan.any():
            tm = np.where((nan & used).any(axis=-1), np.nan, tm)
        return weighted_pool(tm, wt, pool)

    def point(self, values: np.ndarray, pool: str) -> float:
        return float(self._stat(values, self._prepared(np.ones(self.shape[1]), np.ones(self.n_scans)), pool))

    def draws(self, values: np.ndarray, pool: str) -> np.ndarray:
        # the draws' weights once per resampler (shared by every metric, method and difference)
        if self._drawn is None:
            self._drawn = self._prepared(self.m_obj.astype(float), self.m_scan.astype(float))
        return self._stat(values, self._drawn, pool)

    def leaf_weights(self) -> np.ndarray:
        """(B, T, W): the weight of every (target, track) in each draw's mean statistic (each draw's
        weights sum to 1): the draws of a mean are these weights times the values."""
        w, _, wsum, wt = self._prepared(self.m_obj.astype(float), self.m_scan.astype(float))
        with np.errstate(invalid="ignore", divide="ignore"):
            per = np.where(wsum[..., None] > 0, w / wsum[..., None], 0.0) * wt[..., None]
        return per / wt.sum(axis=-1)[:, None, None]

    def estimate(self, values: np.ndarray, pool: str) -> dict[str, float]:
        return estimate(self.point(values, pool), self.draws(values, pool) if self.spread() else None)


def _multiplicities(rng: np.random.Generator, B: int, n: int) -> np.ndarray:
    """(B, n): how often each of n units is drawn in each of B draws of n with replacement."""
    picks = rng.integers(0, n, size=(B, n))
    return np.bincount((np.arange(B)[:, None] * n + picks).ravel(), minlength=B * n).reshape(B, n)


def weighted_pool(x: np.ndarray, w: np.ndarray, pool: str) -> np.ndarray:
    """``pool`` ("mean" | "median") over the last axis of ``x`` with integer weights ``w`` (an
    entry of weight k counts k times; weight 0: left out); a NaN with weight > 0 makes it NaN."""
    x, w = np.broadcast_arrays(np.asarray(x, float), np.asarray(w, float))
    used = w > 0
    real_nan = (np.isnan(x) & used).any(axis=-1)
    if pool == "mean":
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(used, w * np.nan_to_num(x, nan=0.0, posinf=np.inf, neginf=-np.inf), 0.0).sum(axis=-1) \
                / w.sum(axis=-1)
    elif pool == "median":
        key = np.where(used, x, np.inf)
        order = np.argsort(key, axis=-1, kind="stable")
        xs, ws = np.take_along_axis(x, order, -1), np.take_along_axis(np.where(used, w, 0.0), order, -1)
        cum = np.cumsum(ws, axis=-1)
        N = cum[..., -1]
        pick = lambda k: np.take_along_axis(xs, (cum > k[..., None]).argmax(axis=-1)[..., None], -1)[..., 0]
        with np.errstate(invalid="ignore"):
            out = (pick(np.floor((N - 1) / 2)) + pick(np.floor(N / 2))) / 2
        out = np.where(N > 0, out, np.nan)
    else:
        raise ValueError(f"unknown pooling {pool!r} (mean | median)")
    return np.where(real_nan, np.nan, out)


@lru_cache(maxsize=64)
def _cached(structure: tuple[tuple[int, ...], ...], n_boot: int, seed: tuple[int, ...]) -> CrossedResampler:
    W = max(len(s) for s in structure)
    scan_of = np.full((len(structure), W), -1, dtype=np.int64)
    for t, s in enumerate(structure):
        scan_of[t, : len(s)] = s
    return CrossedResampler(scan_of, n_boot, list(seed))


def crossed_draws(structure: Sequence[Sequence[int]], n_boot: int, seed) -> CrossedResampler:
    """The ``CrossedResampler`` of ``structure`` (per target, the scan index of each of its sorted
    tracks), made once per (structure, n_boot, seed) and shared."""
    key = tuple(tuple(int(x) for x in s) for s in structure)
    return _cached(key, int(n_boot), tuple(int(x) for x in np.atleast_1d(seed)))
