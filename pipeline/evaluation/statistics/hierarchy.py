"""The units of one population and their shared draws (``Hierarchy``: seeds -> targets -> tracks),
and the leave-one-target-out check on them: what the engine and the pooled ECE both resample on.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.resampler import Resampler, draws, estimate


class Hierarchy:
    """The units of one population: per seed, its sorted targets and each target's sorted tracks,
    and the shared draws over them.

    ``by_scan`` (one seed whose cells carry a ``scan`` column): the pooled values and paired
    differences resample scans, then the targets seen in each scan, then their tracks in that
    scan (``rs``, the resampler's top level holding scans instead of seeds); per-target values,
    leave-one-target-out and the pooled ECE keep targets, then tracks (``target_rs``)."""

    def __init__(self, frames: Mapping[str, pd.DataFrame], n_boot: int, seed, by_scan: bool = False):
        self.seeds = list(frames)
        self.units = []  # per seed: [(target, [tracks])]
        for s in self.seeds:
            f = frames[s]
            self.units.append([(str(t), sorted(int(x) for x in g["track"].unique()))
                               for t, g in f.groupby("target", sort=True)])
        self.n_boot, self.seed = int(n_boot), seed
        self.target_rs = draws([[len(tr) for _, tr in u] for u in self.units], n_boot, seed)
        self.index = [{(t, tr): (ti, j) for ti, (t, trs) in enumerate(u) for j, tr in enumerate(trs)}
                      for u in self.units]
        first = frames[self.seeds[0]] if self.seeds else None
        self.scans: list[str] = []
        self.by_scan = bool(by_scan and len(self.seeds) == 1 and first is not None and "scan" in first)
        self.rs = self.target_rs
        if self.by_scan:
            self.scans = sorted(str(x) for x in first["scan"].unique())
            self.scan_units = [[(str(t), sorted(int(x) for x in g["track"].unique()))
                                for t, g in first[first["scan"].astype(str) == sc].groupby("target", sort=True)]
                               for sc in self.scans]
            self.scan_index = {(t, tr): (si, ti, j) for si, u in enumerate(self.scan_units)
                               for ti, (t, trs) in enumerate(u) for j, tr in enumerate(trs)}
            if sum(len(tr) for u in self.scan_units for _, tr in u) != len(self.index[0]):
                raise ValueError("resampling scans: a (target, track) lies in more than one scan")
            self.rs = draws([[len(tr) for _, tr in u] for u in self.scan_units], n_boot, [*np.atleast_1d(seed), 3])

    @property
    def targets(self) -> list[str]:
        return [t for t, _ in self.units[0]]

    def n(self) -> dict[str, int]:
        out = {"targets": sum(len(u) for u in self.units), "tracks": sum(len(tr) for u in self.units for _, tr in u)}
        if len(self.seeds) > 1:
            out["seeds"] = len(self.seeds)
        if self.by_scan:
            out["scans"] = len(self.scans)
            out["scan_targets"] = sum(len(u) for u in self.scan_units)
        return out

    def over(self) -> list[str]:
        return (["seeds"] if len(self.seeds) > 1 else []) + (["scans"] if self.by_scan else []) + ["targets", "tracks"]

    def pad(self, tvs: Sequence[pd.DataFrame], column: str, flat: bool = False) -> np.ndarray:
        """Track values of ``column`` from each seed's track frame (target, track, ...), padded to
        ``rs``'s (S, T, W) (``flat`` or no scan level: ``target_rs``'s, seeds -> targets -> tracks)."""
        scan = self.by_scan and not flat
        out = np.zeros(self.rs.shape if scan else self.target_rs.shape)
        for s, tv in enumerate(tvs):
            idx = self.index[s]
            for t, tr, v in zip(tv["target"].astype(str), tv["track"].astype(int), tv[column].to_numpy(float)):
                if scan:
                    out[self.scan_index[(t, tr)]] = v
                else:
                    ti, j = idx[(t, tr)]
                    out[s, ti, j] = v
        return out

    def per_target(self, ti: int) -> Resampler:
        return draws([[len(self.units[0][ti][1])]], self.n_boot, [*np.atleast_1d(self.seed), 1, ti])


def leave_one_out(h: Hierarchy, full: Mapping[str, float], points: np.ndarray, loo_draws: np.ndarray,
                  higher: bool) -> dict:
    """The leave-one-target-out check from the draws already made (jackknife-after-bootstrap):
    ``full`` the estimate on all targets (``target_rs``), ``points`` (T,) the statistic with each
    target left out, ``loo_draws`` (B,) the statistic of each draw's first T - 1 target slots
    (``Resampler.draws(slots=T - 1)``). Target t's interval is the percentile interval of the
    draws whose first T - 1 slots miss t: in distribution a bootstrap of the other T - 1 targets,
    about B (1 - 1/T)^(T - 1) ~ 0.37 B of them (docs/design.md §8, its Monte Carlo error). The
    range of the values and the targets whose removal alone changes the outcome of the whole
    population."""
    names = h.targets
    T = len(names)
    if T < 3:
        return {"loto_min": float("nan"), "loto_max": float("nan"), "loto_flips": [], "loto_flip_outcomes": {}}
    res_full = REC.outcome(*_ends(full), higher)
    flips, to = [], {}
    for name, est in zip(names, loto_estimates(h, points, loo_draws)):
        res = REC.outcome(*_ends(est), higher)
        if res != res_full:
            flips.append(name)
            to[name] = res
    v = np.asarray(points, float)
    v = v[np.isfinite(v)]
    return {"loto_min": float(v.min()) if len(v) else float("nan"), "loto_max": float(v.max()) if len(v) else float("nan"),
            "loto_flips": flips, "loto_flip_outcomes": to}


def loto_estimates(h: Hierarchy, points: np.ndarray, loo_draws: np.ndarray) -> list[dict]:
    """Each target's left-out estimate {"value", "ci_low", "ci_high"} (as ``leave_one_out`` reads
    them; for tests and benchmarks)."""
    out = h.target_rs.left_out(len(h.targets) - 1)                      # (B, T)
    return [estimate(points[ti], loo_draws[out[:, ti]] if out[:, ti].sum() >= 2 else None)
            for ti in range(len(h.targets))]


def _ends(est: Mapping[str, float]) -> tuple[float, float]:
    return est["ci_low"], est["ci_high"]
