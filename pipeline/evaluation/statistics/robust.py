"""Pooled statistics that one target cannot carry, and leave-one-target-out checks.

log10 MGR and NLL are unbounded: one target whose Model Based posterior gives the truth 1e-30000
moves a mean over targets by thousands, whatever the other targets say. For these metrics the
verdict uses the **median over targets of the target values** (a target's value is, as for the
mean, the mean over its tracks of each track's mean over settings). Why this statistic
(docs/design.md, "Robust pooling"): it keeps the population's unit (every target weighs the same,
whatever its number of tracks or cells), it cannot be moved by any single target however extreme
(its breakdown point is half the targets), and it has a bootstrap CI from the same hierarchical
resampling (targets, then tracks within targets) as every other pooled value. A median of all
cells would weigh targets by their cell counts; a trimmed mean would need a trimming share, and
a resample that draws the extreme target more often than the trim leaks it back in.

``Resample`` holds one hierarchical bootstrap's draws so that several statistics (a mean, a
median, an ECE from bin sums) and several methods use the same draws, which is what makes a paired
difference of ratios such as the ECE well defined.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Callable, Sequence

import numpy as np

LEVEL = 0.95
STATISTIC = "median over targets of the target means"


class Resample:
    """Draws of a two-level bootstrap over groups (targets) of sizes ``sizes`` (tracks per target).

    Draw b picks T groups with replacement (``pick`` (B, T)) and, for every slot independently,
    that group's members with replacement (``counts`` (B, T, width): how often member j of the
    slot's group was drawn).
    """

    def __init__(self, sizes: Sequence[int], n_boot: int, seed):
        rng = np.random.default_rng(seed)
        self.sizes = np.asarray(sizes, dtype=np.int64)
        if len(self.sizes) == 0 or np.any(self.sizes < 1):
            raise ValueError(f"Resample: every group needs a member, sizes {self.sizes.tolist()}")
        T, self.width, B = len(self.sizes), int(self.sizes.max()), int(n_boot)
        self.pick = rng.integers(0, T, size=(B, T))
        n = self.sizes[self.pick]                                               # (B, T)
        members = (rng.random((B, T, self.width)) * n[..., None]).astype(np.int64)
        used = np.arange(self.width)[None, None, :] < n[..., None]
        slot = np.arange(B * T).reshape(B, T, 1) * self.width
        flat = (slot + members)[used]
        self.counts = np.bincount(flat, minlength=B * T * self.width).reshape(B, T, self.width).astype(float)
        self.n = n

    def slot_means(self, padded: np.ndarray) -> np.ndarray:
        """(B, T): each slot's resampled mean of its group's members (``padded`` (T, width))."""
        return np.einsum("bsj,bsj->bs", self.counts, np.asarray(padded, float)[self.pick]) / self.n

    def member_weights(self) -> np.ndarray:
        """(B, T, width): weight of every (group, member) in draw b; each draw's weights sum to 1
        (every slot weighs 1/T, shared among its drawn members)."""
        B, T = self.pick.shape
        w = np.zeros((B, T, self.width))
        per = self.counts / (self.n[..., None] * T)
        rows = np.arange(B)
        for s in range(T):  # one slot at a time: no repeated (row, group) index within a statement
            w[rows, self.pick[:, s]] += per[:, s]
        return w


@lru_cache(maxsize=64)
def _cached(sizes: tuple[int, ...], n_boot: int, seed: tuple) -> Resample:
    return Resample(sizes, n_boot, list(seed))


def resample(sizes: Sequence[int], n_boot: int, seed) -> Resample:
    """A ``Resample``, shared by every caller with the same sizes and seed: the metrics and paired
    comparisons of one population reuse the same draws (common random numbers), and a
    leave-one-target-out pass builds each subset's draws once."""
    return _cached(tuple(int(x) for x in sizes), int(n_boot), tuple(int(x) for x in np.atleast_1d(seed)))


def pad(groups: Sequence[np.ndarray]) -> np.ndarray:
    width = max(len(g) for g in groups)
    out = np.zeros((len(groups), width))
    for t, g in enumerate(groups):
        out[t, : len(g)] = g
    return out


def _interval(samples: np.ndarray) -> tuple[float, float]:
    s = np.asarray(samples, float)
    s = s[np.isfinite(s)]
    if not len(s):
        return float("nan"), float("nan")
    lo, hi = np.percentile(s, [50 * (1 - LEVEL), 50 * (1 + LEVEL)])
    return float(lo), float(hi)


def estimate(value: float, samples: np.ndarray) -> dict[str, float]:
    lo, hi = _interval(samples)
    if np.isfinite(value) and np.isfinite(lo):  # percentiles of identical values can miss by one bit
        lo, hi = min(lo, value), max(hi, value)
    return {"value": float(value), "ci_low": lo, "ci_high": hi}


def _stat(name: str) -> Callable[[np.ndarray], np.ndarray]:
    if name == "median":
        return lambda a: np.median(a, axis=-1)
    if name == "mean":
        return lambda a: np.mean(a, axis=-1)
    raise ValueError(f"unknown pooled statistic {name!r} (median | mean)")


def pooled(groups: Sequence[np.ndarray], n_boot: int, seed, stat: str = "median") -> dict[str, float]:
    """``stat`` over groups of the group means, with a hierarchical bootstrap 95 % CI."""
    groups = [np.asarray(g, float) for g in groups if len(g)]
    if not groups:
        return {"value": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    f = _stat(stat)
    value = float(f(np.array([g.mean() for g in groups])))
    rs = resample([len(g) for g in groups], n_boot, seed)
    return estimate(value, f(rs.slot_means(pad(groups))))


def outcome(est: dict, higher_is_better: bool) -> str:
    lo, hi = est["ci_low"], est["ci_high"]
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "not distinguishable"
    if (lo > 0 and higher_is_better) or (hi < 0 and not higher_is_better):
        return "better"
    if (hi < 0 and higher_is_better) or (lo > 0 and not higher_is_better):
        return "worse"
    return "not distinguishable"


def leave_one_out_values(names: Sequence[str], fn: Callable[[np.ndarray], dict], higher_is_better: bool) -> dict:
    """Leave each group out in turn: ``fn(kept indices)`` gives the estimate (value and CI). Returns
    the range of the values and the groups whose removal changes the full population's outcome."""
    n = len(names)
    full = outcome(fn(np.arange(n)), higher_is_better)
    if n < 3:
        return {"loto_min": float("nan"), "loto_max": float("nan"), "loto_flips": [], "loto_flip_outcomes": {},
                "outcome": full}
    values, flips, to = [], [], {}
    for i, name in enumerate(names):
        est = fn(np.array([j for j in range(n) if j != i]))
        values.append(est["value"])
        res = outcome(est, higher_is_better)
        if res != full:
            flips.append(str(name))
            to[str(name)] = res
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return {"loto_min": float(v.min()) if len(v) else float("nan"),
            "loto_max": float(v.max()) if len(v) else float("nan"), "loto_flips": flips,
            "loto_flip_outcomes": to, "outcome": full}


def leave_one_out(names: Sequence[str], groups: Sequence[np.ndarray], n_boot: int, seed, stat: str,
                  higher_is_better: bool) -> dict:
    """The pooled ``stat`` with each group (target) left out in turn: its range, and the groups whose
    removal changes the outcome (better / worse / not distinguishable) of the full population."""
    return leave_one_out_values(names, lambda keep: pooled([groups[k] for k in keep], n_boot, seed, stat),
                                higher_is_better)
