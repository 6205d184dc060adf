"""The units of one population and their shared draws (``Hierarchy``: seeds -> targets -> tracks,
or the design's clusters on top), and the leave-one-target-out check on them: what the engine and the pooled ECE both resample on.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.crossed import crossed_draws
from pipeline.evaluation.statistics.design import Layout
from pipeline.evaluation.statistics.design import withheld as design_withheld
from pipeline.evaluation.statistics.resampler import Resampler, draws, estimate
from pipeline.scene.folds import category_of


CLUSTERS = ("target", "scan", "category", "crossed")
# What each clustering's intervals resample, top level first (a record's ``over``).
OVER = {"target": ["targets", "tracks"], "scan": ["scans", "targets", "tracks"],
        "category": ["categories", "targets", "tracks"], "crossed": ["targets", "scans"]}


class Hierarchy:
    """The units of one population: per seed, its sorted targets and each target's sorted tracks,
    and the shared draws over them.

    ``cluster`` (``evaluate.statistics.cluster``; one seed, else "target") names the design's
    independent unit, the top level of the pooled values' and paired differences' draws (``rs``):
    "target": targets, then tracks; "scan" (cells with a ``scan`` column): scans, then the
    targets seen in each scan, then their tracks in it; "category": categories (a ``category``
    column, else the targets' ``<category>__f<k>`` names), then their targets, then tracks;
    "crossed": targets and scans resampled independently (``crossed.CrossedResampler``).
    Per-target values, leave-one-target-out and the pooled ECE keep targets, then tracks
    (``target_rs``). ``by_scan``: the former spelling of cluster = "scan"."""

    def __init__(self, frames: Mapping[str, pd.DataFrame], n_boot: int, seed, by_scan: bool = False,
                 cluster: str = "target", run_levels: Mapping[str, int] | None = None):
        if cluster not in CLUSTERS:
            raise ValueError(f"evaluate.statistics.cluster = {cluster!r}: one of {', '.join(CLUSTERS)}")
        self.seeds = list(frames)
        self.units = []  # per seed: [(target, [tracks])]
        for s in self.seeds:
            f = frames[s]
            self.units.append([(str(t), sorted(int(x) for x in g["track"].unique()))
                               for t, g in f.groupby("target", sort=True)])
        self.n_boot, self.seed = int(n_boot), seed
        # levels the pooled runs' own designs vary over that their cells no longer name (a seed pool
        # reads summary.json's cells: scans, categories); counted by ``withheld``, never resampled
        self.run_levels = dict(run_levels or {})
        self.target_rs = draws([[len(tr) for _, tr in u] for u in self.units], n_boot, seed)
        self.index = [{(t, tr): (ti, j) for ti, (t, trs) in enumerate(u) for j, tr in enumerate(trs)}
                      for u in self.units]
        first = frames[self.seeds[0]] if self.seeds else None
        if cluster in ("scan", "crossed") and first is not None and "scan" not in first:
            raise ValueError(f"cluster = {cluster!r} needs the cells' 'scan' column (the population has none)")
        cluster = "scan" if by_scan and cluster == "target" and first is not None and "scan" in first else cluster
        if len(self.seeds) != 1 or first is None:
            cluster = "target"        # a seed pool keeps seeds on top
        self.cluster = cluster
        self.groups: list[str] = []
        self.rs = self.target_rs
        self._first = first if len(self.seeds) == 1 else None
        if cluster in ("scan", "category"):
            self._nest(first, cluster, seed)
        elif cluster == "crossed":
            self._cross(first, seed)

    def _nest(self, first: pd.DataFrame, cluster: str, seed) -> None:
        """Groups (scans or categories) on top: each group's targets, each target's tracks in it."""
        f = first.copy()
        if cluster == "category":
            f["_group"] = f["category"].astype(str) if "category" in f else [category_of(t) for t in f["target"].astype(str)]
        else:
            f["_group"] = f["scan"].astype(str)
        self.groups = sorted(f["_group"].unique())
        self.group_units = [[(str(t), sorted(int(x) for x in g["track"].unique()))
                             for t, g in f[f["_group"] == gr].groupby("target", sort=True)] for gr in self.groups]
        self.group_index = {(t, tr): (gi, ti, j) for gi, u in enumerate(self.group_units)
                            for ti, (t, trs) in enumerate(u) for j, tr in enumerate(trs)}
        if sum(len(tr) for u in self.group_units for _, tr in u) != len(self.index[0]):
            raise ValueError(f"resampling {cluster}s: a (target, track) lies in more than one {cluster}")
        self.rs = draws([[len(tr) for _, tr in u] for u in self.group_units], self.n_boot,
                        [*np.atleast_1d(seed), 3 if cluster == "scan" else 4])

    def _cross(self, first: pd.DataFrame, seed) -> None:
        """Targets and scans crossed: the scan of each (target, track)."""
        sc = {(str(t), int(tr)): str(s) for t, tr, s in zip(first["target"], first["track"], first["scan"])}
        per = {}
        for (t, tr), s in sc.items():
            per.setdefault((t, tr), set()).add(s)
        if any(len(v) > 1 for v in per.values()):
            raise ValueError("crossed bootstrap: a (target, track) lies in more than one scan")
        self.groups = sorted(set(sc.values()))
        gi = {g: i for i, g in enumerate(self.groups)}
        self.rs = crossed_draws([[gi[sc[(t, tr)]] for tr in trs] for t, trs in self.units[0]], self.n_boot,
                                [*np.atleast_1d(seed), 5])

    def layout(self) -> tuple[np.ndarray, Layout] | None:
        """(the leaves' flat positions in ``rs``'s padded values, their ``design.Layout``): the point
        statistic's weights and each track's target, scan (a ``scan`` column) and, clustered so,
        category. None for a seed pool (seeds on top: the draws keep them)."""
        if self._first is None:
            return None
        if getattr(self, "_layout", None) is None:
            f = self._first
            scan = ({(str(t), int(tr)): str(s) for t, tr, s in zip(f["target"], f["track"], f["scan"])}
                    if "scan" in f else {})
            if self.nested:
                tops = [(gi, ti, t, trs, len(u), len(self.group_units)) for gi, u in enumerate(self.group_units)
                        for ti, (t, trs) in enumerate(u)]
            else:
                tops = [(0, ti, t, trs, len(self.units[0]), 1) for ti, (t, trs) in enumerate(self.units[0])]
            pos, w, lab = [], [], {"targets": [], "scans": [], "categories": []}
            for gi, ti, t, trs, n_t, n_g in tops:
                for j, tr in enumerate(trs):
                    pos.append(np.ravel_multi_index((gi, ti, j), self.rs.shape))
                    w.append(1.0 / (n_g * n_t * len(trs)))
                    lab["targets"].append(t)
                    lab["scans"].append(self.groups[gi] if self.cluster == "scan" else scan.get((t, tr), ""))
                    lab["categories"].append(self.groups[gi] if self.cluster == "category" else "")
            labels = {k: np.unique(np.asarray(v), return_inverse=True)[1].ravel() for k, v in lab.items()}
            self._layout = (np.asarray(pos, dtype=np.int64), Layout(np.asarray(w), labels))
        return self._layout

    def withheld(self) -> str | None:
        """Why no interval of this population's pooled statistics is calibrated (``design.withheld``
        of the levels it varies over: a level with fewer than ``design.MIN_CLUSTERS`` units), else
        None. The one rule for every pooled statistic: the design's t interval of a mean and the
        percentile interval of a median, an infinite value or the pooled ECE alike; a seed pool's
        percentile interval too, whose draws resample the seeds on top, then each seed's targets
        (its levels: seeds, targets, and the pooled runs' own ``run_levels``)."""
        lay = self.layout()
        levels = dict(lay[1].levels()) if lay is not None else {
            "seeds": len(self.seeds), "targets": min((len(u) for u in self.units), default=0)}
        levels.update({k: int(g) for k, g in self.run_levels.items() if k not in levels})
        return design_withheld({k: g for k, g in levels.items() if g > 1})

    @property
    def by_scan(self) -> bool:
        return self.cluster == "scan"

    @property
    def nested(self) -> bool:
        """Whether ``rs`` holds a group level above the targets (its values padded by group)."""
        return self.cluster in ("scan", "category")

    @property
    def scans(self) -> list[str]:
        return self.groups if self.cluster in ("scan", "crossed") else []

    @property
    def targets(self) -> list[str]:
        return [t for t, _ in self.units[0]]

    def n(self) -> dict[str, int]:
        out = {"targets": sum(len(u) for u in self.units), "tracks": sum(len(tr) for u in self.units for _, tr in u)}
        if len(self.seeds) > 1:
            out["seeds"] = len(self.seeds)
        if self.cluster in ("scan", "crossed"):
            out["scans"] = len(self.groups)
        elif self._first is not None and "scan" in self._first and self._first["scan"].nunique() > 1:
            out["scans"] = int(self._first["scan"].nunique())     # the design interval counts them
        if self.cluster == "scan":
            out["scan_targets"] = sum(len(u) for u in self.group_units)
        if self.cluster == "category":
            out["categories"] = len(self.groups)
        return out

    def over(self) -> list[str]:
        return (["seeds"] if len(self.seeds) > 1 else []) + OVER[self.cluster]

    def pad(self, tvs: Sequence[pd.DataFrame], column: str, flat: bool = False) -> np.ndarray:
        """Track values of ``column`` from each seed's track frame (target, track, ...), padded to
        ``rs``'s (S, T, W) (``flat`` or no group level: ``target_rs``'s, seeds -> targets -> tracks)."""
        grouped = self.nested and not flat
        out = np.zeros(self.rs.shape if grouped else self.target_rs.shape)
        for s, tv in enumerate(tvs):
            idx = self.index[s]
            for t, tr, v in zip(tv["target"].astype(str), tv["track"].astype(int), tv[column].to_numpy(float)):
                if grouped:
                    out[self.group_index[(t, tr)]] = v
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
