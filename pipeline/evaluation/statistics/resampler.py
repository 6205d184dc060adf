"""The one hierarchical resampler and the one interval rule (the percentile and its infinity rule: ``spec.percentile``).

Levels: seeds (classifier training runs) -> targets -> tracks, as the data has them: one seed
is a population of one evaluate run, one target is a per-target CI over its tracks, one
(realization) group is the single-track CI over realizations. A draw picks the seeds with
replacement, then for every drawn seed slot its targets with replacement, then for every drawn
target slot its tracks with replacement (a unit drawn twice gets two independent inner draws).

Draws are made once per (structure, n_boot, seed) and cached (``draws``): every metric, method
and paired difference of one population reads the same draws, so a paired difference is the
difference of the two methods' resampled statistics when that statistic is linear, and two
metrics that are the same quantity up to a positive factor get the same interval up to that
factor (common random numbers).

Interval: the percentile interval (2.5th and 97.5th percentiles of the draws' statistic, linear
interpolation), clamped to contain the point value (percentiles of identical values can miss it
in the last bit).

Infinity: +inf and -inf are values like any other (a mean with +inf is +inf; a median may stay
finite). A percentile that interpolates toward an infinite draw is that infinity, so an interval
end can be +-inf: the interval is unbounded on that side (JSON writes it as null; the records
say so). A draw whose statistic is undefined (NaN, e.g. inf - inf) makes the interval undefined:
no CI, and the outcome is "not distinguishable".
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from pipeline.evaluation.metrics.spec import percentile

LEVEL = 0.95


def interval(draws: np.ndarray, axis: int = -1, level: float = LEVEL) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval of ``draws`` along ``axis``: the one percentile
    (``spec.percentile``, its infinity rule) at the ends of the ``level`` interval (``LEVEL``;
    the Holm steps ask for wider ones: ``multiplicity``)."""
    lo, hi = percentile(draws, [50 * (1 - level), 50 * (1 + level)], axis=axis)
    return lo, hi


def estimate(value: float, draws: np.ndarray | None, level: float = LEVEL) -> dict[str, float]:
    """{"value", "ci_low", "ci_high"}: the point value and the percentile interval of its draws
    (None or fewer than two resampled units: no interval)."""
    v = float(value)
    if draws is None:
        return {"value": v, "ci_low": math.nan, "ci_high": math.nan}
    lo, hi = (float(x) for x in interval(draws, level=level))
    if not math.isnan(v) and not math.isnan(lo):
        lo, hi = min(lo, v), max(hi, v)
    return {"value": v, "ci_low": lo, "ci_high": hi}


def _stat(x: np.ndarray, valid: np.ndarray, pool: str) -> np.ndarray:
    """``pool`` ("mean" | "median") over the last axis of the entries where ``valid``; a NaN
    among the valid entries makes the result NaN."""
    if pool not in ("mean", "median"):
        raise ValueError(f"unknown pooling {pool!r} (mean | median)")
    real_nan = (np.isnan(x) & valid).any(axis=-1)
    with np.errstate(invalid="ignore"):
        if pool == "mean":
            out = np.where(valid, x, 0.0).sum(axis=-1) / valid.sum(axis=-1)
        else:
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                out = np.nanmedian(np.where(valid, x, np.nan), axis=-1)
    return np.where(real_nan, np.nan, out)


class Resampler:
    """Draws of the seeds -> targets -> tracks bootstrap over ``structure``: for each seed, the
    track count of each of its targets (every count >= 1).

    ``ps`` (B, S): the seed of each seed slot; ``pt`` (B, S, T): the target (within that seed)
    of each target slot, ``valid`` where the slot exists (the drawn seed has that many targets);
    ``counts`` (B, S, T, W): how often each track of the slot's target was drawn.
    """

    def __init__(self, structure: Sequence[Sequence[int]], n_boot: int, seed):
        self.n_targets = np.array([len(s) for s in structure], dtype=np.int64)
        if len(self.n_targets) == 0 or np.any(self.n_targets < 1):
            raise ValueError(f"Resampler: every seed needs a target, structure {structure!r}")
        S, T = len(self.n_targets), int(self.n_targets.max())
        self.n_tracks = np.zeros((S, T), dtype=np.int64)
        for s, sizes in enumerate(structure):
            self.n_tracks[s, : len(sizes)] = sizes
        if any(int(n) < 1 for sizes in structure for n in sizes):
            raise ValueError(f"Resampler: every target needs a track, structure {structure!r}")
        W, B = int(self.n_tracks.max()), int(n_boot)
        self.shape, self.n_boot = (S, T, W), B
        rng = np.random.default_rng(seed)
        self.ps = rng.integers(0, S, size=(B, S)) if S > 1 else np.zeros((B, 1), dtype=np.int64)
        nts = self.n_targets[self.ps]                                            # (B, S)
        self.valid = np.arange(T)[None, None, :] < nts[..., None]                # (B, S, T)
        self.pt = np.where(self.valid, (rng.random((B, S, T)) * nts[..., None]).astype(np.int64), 0)
        n = np.where(self.valid, self.n_tracks[self.ps[..., None], self.pt], 0)  # (B, S, T)
        members = (rng.random((B, S, T, W)) * n[..., None]).astype(np.int64)
        used = np.arange(W)[None, None, None, :] < n[..., None]
        slot = np.arange(B * S * T).reshape(B, S, T, 1) * W
        self.counts = np.bincount((slot + members)[used], minlength=B * S * T * W).reshape(B, S, T, W).astype(float)
        self.n = n

    def leaves_valid(self) -> np.ndarray:
        """(S, T, W): which padded (seed, target, track) entries hold data."""
        _, T, W = self.shape
        tv = np.arange(T)[None, :] < self.n_targets[:, None]
        return tv[..., None] & (np.arange(W)[None, None, :] < self.n_tracks[..., None])

    def point(self, values: np.ndarray, pool: str) -> float:
        """The statistic on the data itself: per seed, ``pool`` over its targets of the target
        means (mean over tracks); the mean over seeds. ``values`` (S, T, >= W), padded."""
        v = np.asarray(values, float)[..., : self.shape[2]]
        lv = self.leaves_valid()
        with np.errstate(invalid="ignore"):
            tm = np.where(lv, v, 0.0).sum(axis=-1) / np.maximum(self.n_tracks, 1)
        tm = np.where((np.isnan(v) & lv).any(axis=-1), np.nan, tm)
        return float(np.mean(_stat(tm, lv.any(axis=-1), pool)))

    def slot_means(self, values: np.ndarray) -> np.ndarray:
        """(B, S, T): each target slot's mean of its resampled tracks (NaN where no slot)."""
        v = np.asarray(values, float)[..., : self.shape[2]][self.ps[..., None], self.pt]   # (B, S, T, W)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(self.counts > 0, self.counts * v, 0.0).sum(axis=-1) / self.n
        return np.where(self.valid, s, np.nan)

    def draws(self, values: np.ndarray, pool: str, slots: int | None = None) -> np.ndarray:
        """(B,): the statistic of ``point`` in every draw; ``slots``: of each seed slot's first
        ``slots`` target slots only (a draw of that many targets: leave-one-target-out)."""
        k = self.shape[1] if slots is None else int(slots)
        return _stat(self.slot_means(values)[..., :k], self.valid[..., :k], pool).mean(axis=-1)

    def leave_one_out_points(self, values: np.ndarray, pool: str) -> np.ndarray:
        """(T,): ``point`` of one seed's population with each target left out in turn (the pool of
        the other targets' means; a NaN among them makes it NaN)."""
        v = np.asarray(values, float)[..., : self.shape[2]]
        lv = self.leaves_valid()
        with np.errstate(invalid="ignore"):
            tm = np.where(lv, v, 0.0).sum(axis=-1) / np.maximum(self.n_tracks, 1)
        tm = np.where((np.isnan(v) & lv).any(axis=-1), np.nan, tm)[0, : self.n_targets[0]]    # (T,)
        T = len(tm)
        keep = ~np.eye(T, dtype=bool)                                            # row t: every target but t
        return _stat(np.broadcast_to(tm, (T, T)), keep, pool)

    def spread(self) -> bool:
        """Whether some level has two units to resample (else no interval)."""
        return bool(len(self.n_targets) > 1 or self.n_targets[0] > 1 or self.n_tracks[0, 0] > 1)

    def estimate(self, values: np.ndarray, pool: str) -> dict[str, float]:
        """``point`` with its interval; no interval when no level has two units to resample."""
        return estimate(self.point(values, pool), self.draws(values, pool) if self.spread() else None)

    def leaf_weights(self, slots: int | None = None) -> np.ndarray:
        """(B, S, T, W): weight of every (seed, target, track) in each draw of the mean statistic
        (each seed slot 1/S, each of its target slots an equal share, shared among the drawn
        tracks); each draw's weights sum to 1. For statistics of weighted sums (the ECE).
        ``slots``: of each seed slot's first ``slots`` target slots only (as in ``draws``)."""
        B, S = self.ps.shape
        S0, T, W = self.shape
        k = T if slots is None else int(slots)
        valid, pt = self.valid[..., :k], self.pt[..., :k]
        nts = valid.sum(axis=-1)                                                 # (B, S)
        with np.errstate(invalid="ignore", divide="ignore"):
            per = np.where(valid[..., None], self.counts[:, :, :k] / (self.n[..., :k, None] * nts[..., None, None] * S),
                           0.0)
        out = np.zeros((B, S0, T, W))
        b = np.broadcast_to(np.arange(B)[:, None, None], pt.shape)
        s = np.broadcast_to(self.ps[..., None], pt.shape)
        np.add.at(out, (b, s, pt), per)
        return out

    def left_out(self, slots: int) -> np.ndarray:
        """(B, T): for one seed, whether target t is absent from the draw's first ``slots`` target
        slots. Given that, those slots are ``slots`` draws with replacement from the other targets,
        so the draws where it holds are draws of the population without t (jackknife-after-bootstrap)."""
        B = self.n_boot
        T = int(self.n_targets[0])
        seen = np.zeros(B * T, dtype=bool)
        seen[(np.arange(B)[:, None] * T + self.pt[:, 0, : int(slots)]).ravel()] = True
        return ~seen.reshape(B, T)

    def point_weights(self) -> np.ndarray:
        """(S, T, W): the leaf weights of the data itself."""
        lv = self.leaves_valid()
        S = len(self.n_targets)
        w = lv / (np.maximum(self.n_tracks, 1)[..., None] * self.n_targets[:, None, None] * S)
        return np.where(lv, w, 0.0)


@lru_cache(maxsize=256)
def _cached(structure: tuple[tuple[int, ...], ...], n_boot: int, seed: tuple[int, ...]) -> Resampler:
    return Resampler(structure, n_boot, list(seed))


def draws(structure: Sequence[Sequence[int]], n_boot: int, seed) -> Resampler:
    """The ``Resampler`` of ``structure``, made once per (structure, n_boot, seed) and shared."""
    key = tuple(tuple(int(n) for n in s) for s in structure)
    return _cached(key, int(n_boot), tuple(int(x) for x in np.atleast_1d(seed)))


def wilson_interval(k: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson 95 % interval of a proportion k/n of independent draws (a held-out accuracy over the
    images drawn; a share of simulated realizations): no hierarchy to resample."""
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def draw_seconds(structure: Sequence[Sequence[int]], n_boot: int, trial: int = 20_000) -> float:
    """Seconds the ``n_boot`` draws of one statistic take on ``structure``: a run of up to ``trial``
    draws timed here and scaled linearly (every array of the resampler grows linearly with the
    draws; a trial much smaller than that stays in cache and underestimates several-fold)."""
    import time

    n = min(int(n_boot), int(trial))
    t0 = time.perf_counter()
    r = Resampler(structure, n, [0])
    r.draws(np.random.default_rng(0).random(r.shape), "mean")
    return (time.perf_counter() - t0) * n_boot / n

