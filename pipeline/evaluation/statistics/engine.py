"""The statistics engine: every pooled value, paired difference, interval and verdict record.

The population (evaluate), its settings and ablations, the seed pooling (study) and the compare
page call ``block``; the single-track tables call ``over_realizations``. A mean of one run's
finite track values takes its interval from the design (``design``: the multiway cluster-robust t
over targets, the scans the cells name and the categories it clusters on; withheld, with the
reason, where a level has too few units); anything else (a median, an infinite value, a seed pool,
the pooled ECE) resamples with ``resampler.draws`` (one hierarchy: seeds -> targets -> tracks) and
takes the percentile interval with its infinity rule. Targets pool as the metric spec says
(``spec.pool_of``: the mean, or the median over targets for unbounded metrics) and
``records.outcome`` labels, so the number shown, its CI and its verdict are one statistic
wherever they appear; the primary family's records also carry their Holm-adjusted verdicts
(``multiplicity``, on the same statistic).

Units: a cell is one (target, track, setting); a track's value is the mean over its settings of
the cell values, a target's the mean over its tracks, a seed's the ``pool`` over its targets, the
pooled value the mean over seeds (one seed: that seed's).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.metrics.labels import comparison_key, comparisons, ordered_methods
from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.design import estimate as design_estimate
from pipeline.evaluation.statistics.hierarchy import Hierarchy, leave_one_out
from pipeline.evaluation.statistics.multiplicity import holm
from pipeline.evaluation.statistics.resampler import draws, estimate, interval
from pipeline.evaluation.statistics.pooled_calibration import pooled_ece
from pipeline.infra.config.evaluation import BOOTSTRAP

KEYS = ["target", "track", "setting"]


def track_values(cells: pd.DataFrame, metrics: Sequence[str]) -> pd.DataFrame:
    """Cell rows -> one row per (method, target, track): the mean over the track's settings."""
    return cells.groupby(["method", "target", "track"], sort=True)[list(metrics)].mean().reset_index()


def aligned_cells(cells: pd.DataFrame, a: str, b: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The cells of ``a`` and of ``b`` indexed by KEYS, both in the index's order; ValueError unless
    the two methods were run on the same cells."""
    x = cells[cells["method"] == a].set_index(KEYS).sort_index()
    y = cells[cells["method"] == b].set_index(KEYS).sort_index()
    if not x.index.equals(y.index):
        raise ValueError(f"paired differences: {a} and {b} were not run on the same cells")
    return x, y


def paired_cells(cells: pd.DataFrame, a: str, b: str, metrics: Sequence[str],
                 aligned: tuple[pd.DataFrame, pd.DataFrame] | None = None) -> pd.DataFrame:
    """``a - b`` on the same cells (method "diff"); ``aligned``: ``aligned_cells(cells, a, b)``
    when the caller has it."""
    x, y = aligned if aligned is not None else aligned_cells(cells, a, b)
    d = (x[list(metrics)] - y[list(metrics)]).reset_index()
    d["method"] = "diff"
    return d


def saturation(diff_src: pd.DataFrame, a: str, b: str, metric: str,
               aligned: tuple[pd.DataFrame, pd.DataFrame] | None = None) -> tuple[int, int]:
    """(cells where both methods sit at the metric's best value, cells where both sit at its worst).
    ``aligned``: ``aligned_cells(diff_src, a, b)`` made once for every metric of the pair."""
    xf, yf = aligned if aligned is not None else aligned_cells(diff_src, a, b)
    x, y = xf[metric], yf[metric]
    m = M.METRICS[metric]
    at = (lambda v: ((np.abs(x - v) < 1e-12) & (np.abs(y - v) < 1e-12)).sum())
    return (int(at(m.best)) if m.best is not None else 0), (int(at(m.worst)) if m.worst is not None else 0)


DESIGN_FIELDS = ("interval", "se", "df", "levels", "withheld")


def _range(metric: str) -> tuple[float, float] | None:
    """A bounded metric's range (a pooled value's interval stays inside it)."""
    m = M.METRICS.get(metric)
    if m is None or m.best is None or m.worst is None:
        return None
    return min(m.best, m.worst), max(m.best, m.worst)


def _design_estimate(h: Hierarchy, v: np.ndarray, pool: str, clamp=None):
    """(the estimate with its interval from the design, its ``design.TStat``) of padded values ``v``
    where the statistic is a mean of finite track values of one run (``design``); None otherwise
    (a median, an infinite value, a seed pool: the percentile interval of the shared draws)."""
    lay = h.layout()
    if lay is None or pool != "mean":
        return None
    pos, layout = lay
    x = np.asarray(v, float).ravel()[pos]
    if not np.isfinite(x).all():
        return None
    return design_estimate(x, layout, clamp, n_boot=h.n_boot, seed=h.seed)


def _boot_estimate(est: dict, why: str | None = None) -> dict:
    """A percentile-bootstrap estimate; ``why`` (``Hierarchy.withheld``): its interval is withheld by
    the same rule as a mean's (no CI, no verdict), the point value kept."""
    out = {**est, "interval": "percentile bootstrap"}
    return withhold(out, why) if why else out


def withhold(est: dict, why: str) -> dict:
    """``est`` without its interval, saying why (``design.withheld``)."""
    return {**est, "ci_low": float("nan"), "ci_high": float("nan"), "withheld": why}


def over_of(a, over: list[str]) -> list[str]:
    """What an interval varies over: the clustering's levels (``over``), and the scans where the
    design interval counts them and the clustering does not name them (after the top level)."""
    if a is None or "scans" not in a[0]["levels"] or "scans" in over:
        return list(over)
    return [over[0], "scans", *over[1:]]


def _loto(h: Hierarchy, values: np.ndarray, pool: str, higher: bool) -> dict:
    """Leave-one-target-out on targets -> tracks from the draws already made (``leave_one_out``)."""
    rs = h.target_rs
    return leave_one_out(h, rs.estimate(values, pool), rs.leave_one_out_points(values, pool),
                         rs.draws(values, pool, slots=rs.shape[1] - 1), higher)


def block(frames: Mapping[str, pd.DataFrame], methods: Sequence[str], metrics: Sequence[str], comparisons,
          n_boot: int, seed, *, primary: Sequence[str] = (), per_target: bool = True, loto: bool = True,
          ece: Mapping | None = None, by_scan: bool = False, cluster: str = "target", family=None,
          exclude=(), run_levels: Mapping[str, int] | None = None) -> dict:
    """{"pooled", "per_target", "paired", "paired_per_target", "records"} (+ "reliability" with
    ``ece``) of cell frames per seed (one seed: an evaluate run). ``ece``: {"sums": track bin sums
    (``pooled_calibration.track_sums``), "methods"}: the pooled ECE joins as a metric. ``cluster``:
    the top level of the draws (``Hierarchy``: target, scan, category, crossed; ``by_scan``: scan);
    every pooled value and record says which (``cluster``) and over what it varies (``over``).
    ``family``: the Holm family's predicate (``multiplicity.holm``; default the declared primary one);
    ``exclude``: (comparison, metric) left out of it (the declared primary comparison, tested alone).
    ``run_levels``: a seed pool's runs' own levels beyond targets (``run_levels``), for the withholding rule."""
    h = Hierarchy(frames, n_boot, seed, by_scan=by_scan, cluster=cluster, run_levels=run_levels)
    metrics = [k for k in metrics if all(k in f for f in frames.values())]
    tvs = {m: [track_values(f[f["method"] == m], metrics) for f in frames.values()] for m in methods}
    n, over = h.n(), h.over()
    n_cells = int(sum(len(f[f["method"] == methods[0]]) for f in frames.values())) if methods else 0
    out: dict = {"pooled": {}, "per_target": {}, "paired": {}, "paired_per_target": {}, "records": []}
    boot: dict[tuple[str, str], np.ndarray | None] = {}   # each record's draws, for the Holm steps
    single = len(h.seeds) == 1
    why = h.withheld()   # the one rule: a level the run varies over with too few units
    for m in methods:
        for k in metrics:
            v = h.pad(tvs[m], k)
            a = _design_estimate(h, v, M.pool_of(k), _range(k))
            out["pooled"].setdefault(m, {})[k] = {**(a[0] if a else _boot_estimate(h.rs.estimate(v, M.pool_of(k)), why)),
                                                  "pooling": M.pool_of(k), "over": over_of(a, over), "cluster": h.cluster,
                                                  "n": n}
            if per_target and single:
                vt = h.pad(tvs[m], k, flat=True) if h.nested else v
                for ti, t in enumerate(h.targets):
                    out["per_target"].setdefault(t, {}).setdefault(m, {})[k] = h.per_target(ti).estimate(
                        vt[:, ti: ti + 1], "mean")
    for a, b in comparisons:
        if a not in methods or b not in methods:
            continue
        key = comparison_key(a, b)
        # each frame's two methods aligned once: for the differences and every metric's saturation
        pairs = [aligned_cells(f, a, b) for f in frames.values()]
        dfs = [paired_cells(f, a, b, metrics, p) for f, p in zip(frames.values(), pairs)]
        dtv = [track_values(d, metrics) for d in dfs]
        for k in metrics:
            higher = M.higher_is_better(k)
            v = h.pad(dtv, k)
            vt = h.pad(dtv, k, flat=True) if h.nested else v
            pool = M.pool_of(k)
            d = np.concatenate([x[k].to_numpy(float) for x in dfs])
            wins, losses = (d > 0, d < 0) if higher else (d < 0, d > 0)
            a = _design_estimate(h, v, pool)
            if a:
                base, boot[(key, k)] = a
            else:
                boot[(key, k)] = h.rs.draws(v, pool) if h.rs.spread() and not why else None
                base = _boot_estimate(estimate(h.rs.point(v, pool), boot[(key, k)]), why)
            est = {**base, "wins": float(wins.mean()), "losses": float(losses.mean()),
                   "n_cells": len(d), "unit": "cells", "better": "higher" if higher else "lower",
                   "pooling": pool, "over": over_of(a, over), "cluster": h.cluster, "n": n}
            out["paired"].setdefault(key, {})[k] = est
            extra = {}
            if per_target and single:
                for ti, t in enumerate(h.targets):
                    out["paired_per_target"].setdefault(key, {}).setdefault(t, {})[k] = h.per_target(ti).estimate(
                        vt[:, ti: ti + 1], "mean")
            if loto and single:
                extra = _loto(h, vt, pool, higher)
                est.update(extra)
            top, bottom = (saturation(next(iter(frames.values())), a, b, k, pairs[0]) if single and k in M.METRICS
                           else (0, 0))
            out["records"].append(REC.record(key, k, est, pooling=pool, better=est["better"], over=est["over"],
                                             cluster=h.cluster, n={**n, "cells": n_cells}, primary=k in primary, wins=est["wins"],
                                             losses=est["losses"], unit="cells", ceiling_cells=top,
                                             floor_cells=bottom, **{x: extra[x] for x in ("loto_min", "loto_max",
                                                                                           "loto_flips") if x in extra},
                                             **{x: est[x] for x in DESIGN_FIELDS if x in est}))
    if ece is not None and single:
        e = pooled_ece(h, ece["sums"], methods, comparisons, per_target=per_target, loto=loto)
        over = [x for x in over if x == "seeds"] + ["targets", "tracks"]   # the pooled ECE: targets, then tracks
        for m, per in e["pooled"].items():
            for k, est in per.items():
                out["pooled"].setdefault(m, {})[k] = {**(withhold(est, why) if why else est),
                                                      "pooling": M.pool_of(k), "over": over,
                                                      "cluster": "target", "n": n}
        for t, per in e["per_target"].items():
            for m, vals in per.items():
                out["per_target"].setdefault(t, {}).setdefault(m, {}).update(vals)
        for key, per in e["paired"].items():
            for k, est in per.items():
                est.update({"pooling": M.pool_of(k), "over": over, "cluster": "target", "n": n},
                           **(withhold(est, why) if why else {}))
                out["paired"].setdefault(key, {})[k] = est
                out["records"].append(REC.record(key, k, est, pooling=M.pool_of(k), better="lower", over=over,
                                                 cluster="target", n={**n, "cells": n_cells}, primary=k in primary, wins=est["wins"],
                                                 losses=est["losses"], unit="targets",
                                                 **{x: est[x] for x in ("loto_min", "loto_max", "loto_flips",
                                                                        "withheld") if x in est}))
        for key, per in e["paired_per_target"].items():
            for t, vals in per.items():
                out["paired_per_target"].setdefault(key, {}).setdefault(t, {}).update(vals)
        out["reliability"] = e["reliability"]
        boot.update(e["draws"])
    order = {k: i for i, k in enumerate(list(metrics) + list(M.POOLED_METRICS))}
    comps = [comparison_key(a, b) for a, b in comparisons]
    out["records"].sort(key=lambda r: (comps.index(r["comparison"]), order.get(r["metric"], len(order))))
    holm(out["records"], boot, family, exclude)
    return out


def population_block(cells: pd.DataFrame, methods: Sequence[str], metrics: Sequence[str], comparisons,
                     n_boot: int, seed, **kw) -> dict:
    """``block`` of one run's cells (one seed)."""
    return block({"run": cells}, methods, metrics, comparisons, n_boot, seed, **kw)


def summary_cells(cells: Sequence[Mapping], methods: Sequence[str] | None = None) -> pd.DataFrame:
    """``summary.json``'s ``population.cells`` (one entry per (target, track, setting) with every
    method's cell metrics) as the long cell frame ``block`` takes."""
    rows = []
    for c in cells:
        for m, vals in (c.get("values") or {}).items():
            if methods is None or m in methods:
                rows.append({"target": str(c["target"]), "track": int(c["track"]), "setting": str(c["setting"]),
                             "method": m, **{k: (np.nan if v is None else float(v)) for k, v in vals.items()}})
    return pd.DataFrame(rows)


def seed_block(cells_by_seed: Mapping[str, Sequence[Mapping]], methods: Sequence[str], metrics: Sequence[str],
               comparisons, n_boot: int, seed=0, primary: Sequence[str] = (),
               run_levels: Mapping[str, int] | None = None) -> dict:
    """``block`` over several seeds' ``population.cells`` (seeds -> targets -> tracks); withheld,
    as every pooled statistic, where a level it varies over (the seeds, each seed's targets, the
    runs' own ``run_levels``) has too few units."""
    frames = {str(s): summary_cells(c, methods) for s, c in sorted(cells_by_seed.items())}
    out = block(frames, methods, metrics, comparisons, n_boot, seed, primary=primary, per_target=False, loto=False,
                run_levels=run_levels)
    out["seeds"] = list(frames)
    return out


def seed_pool(populations: Mapping[str, Mapping]) -> dict | None:
    """The one seed pool (``viewfuse study`` and ``viewfuse compare``): ``seed_block`` over several
    runs' ``population`` blocks of summary.json, keyed by seed name: the methods their cells hold,
    the metrics every seed's cells hold, the runs' own resample count (``population.bootstrap``, the
    ``evaluate.bootstrap`` default where a summary lacks it) and primary metrics. None without a
    population, or when one of them holds no cells (a pool without a seed would overstate)."""
    pops = {str(k): p for k, p in populations.items()}
    if not pops or not all(p.get("cells") for p in pops.values()):
        return None
    methods = ordered_methods({m for p in pops.values() for c in p["cells"] for m in (c.get("values") or {})})
    metrics = [k for k in M.METRICS if all(k in (p["cells"][0].get("values") or {}).get(methods[0], {})
                                           for p in pops.values())]
    first = next(iter(pops.values()))
    n_boot = int(first.get("bootstrap") or BOOTSTRAP)
    primary = next((p.get("primary_metrics") for p in pops.values() if p.get("primary_metrics")), ())
    levels: dict[str, int] = {}
    for p in pops.values():
        for k, g in run_levels(p).items():
            levels[k] = min(g, levels.get(k, g))
    return seed_block({k: p["cells"] for k, p in pops.items()}, methods, metrics, comparisons(), n_boot,
                      primary=tuple(primary or ()), run_levels=levels)


def run_levels(pop: Mapping) -> dict[str, int]:
    """The levels beyond targets a run's own intervals vary over (its records' ``n``: scans,
    categories), which its summary's cells do not name: a seed pool counts them in the
    withholding rule (pooling seeds adds no scan or category)."""
    n = next((r.get("n") for r in pop.get("records") or () if isinstance(r, Mapping) and r.get("n")), None) or {}
    return {k: int(n[k]) for k in ("scans", "categories") if n.get(k)}


def over_realizations(mats: Mapping[str, np.ndarray], params: M.Params, n_boot: int, seed=0) -> dict[str, dict]:
    """Each metric of one (R, K) set of per-step values (``spec.matrices``) with its interval over
    realizations (the single-track tables: only the localization noise varies), from the shared
    resampler with realizations as its one level."""
    R = next(iter(mats.values())).shape[0]
    point = M.compute(mats, params=params)
    rs = draws([[R]], n_boot, seed)
    counts = rs.counts[:, 0, 0, :R].astype(np.int64)                                 # (B, R), rows sum to R
    idx = np.repeat(np.tile(np.arange(R), rs.n_boot), counts.ravel()).reshape(rs.n_boot, R)
    boot = M.compute({k: v[idx] for k, v in mats.items()}, params=params)
    out = {}
    for k, v in point.items():
        if R < 2:
            out[k] = {"value": float(v), "ci_low": float("nan"), "ci_high": float("nan")}
            continue
        lo, hi = (float(x) for x in interval(boot[k]))
        out[k] = {"value": float(v), "ci_low": min(lo, float(v)), "ci_high": max(hi, float(v))}
    return out


def over_groups(groups: Sequence[np.ndarray], n_boot: int, seed) -> dict[str, float]:
    """The mean over groups of their members' mean, with its interval over groups, then members
    (two levels; empty groups are left out). The draws are the shared ones of that structure."""
    groups = [np.asarray(g, float) for g in groups if len(g)]
    if not groups:
        return {"value": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    sizes = [len(g) for g in groups]
    values = np.zeros((1, len(groups), max(sizes)))
    for t, g in enumerate(groups):
        values[0, t, : len(g)] = g
    return draws([sizes], n_boot, seed).estimate(values, "mean")


def over_members(values: np.ndarray, n_boot: int, seed) -> dict[str, float]:
    """The mean of one group's values with its interval over them (one level)."""
    return over_groups([values], n_boot, seed)
