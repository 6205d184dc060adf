"""The paper's §5.5 test as the paper ran it, and MGR percentiles over every track of a method.

§5.5.2 (Fig. 17) runs pose sampling only ("assuming model uncertainty negligible, the output of our
method is obtained according to Eq. (42)"): here the poses-only variant (``evaluate.attribution``:
With Uncertainty with each step's dropout samples replaced by their mean) against Model Based, in
the biased-plus-randomized setting, on the paper's event: a wrong class at least 10 times as
probable as the truth at the last step (``wrong10_final``: log10 MGR >= 1). One engine record
(``grid.primary.comparison_record``: the run's clustering, no multiplicity family); "missing" says
why where the run has no such setting or no poses-only cells.

The paper's MGR percentiles are over its runs (Table 1: 300 tracks), not a median of per-cell
percentiles: ``mgr_block`` takes the 75th and 95th percentiles of the final log10 MGR over every
(track, realization) of a method in a scope (every setting, or the §5.5 one), each with a 95 % CI
that follows the run's clustering as the engine's intervals do: its units are the targets, the
scans where the cells name two or more, and the categories where the run clusters on them; each
draw resamples every level's units with replacement, independently (objects x scans crossed: the
pigeonhole bootstrap, conservative where track noise dominates), a (target, scan) block of values
weighing the product of its units' counts. The paired difference of the 95th percentiles is taken
on the same draws. A level with fewer than ``design.MIN_CLUSTERS`` units gives no interval and no
verdict (``withheld``, as every mean's interval), and where the interval spans more than one decade
(or is unbounded) no verdict is given: an interval that wide decides nothing about how far a wrong
class beats the truth.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.grid.primary import comparison_record, setting_labels
from pipeline.evaluation.metrics.labels import comparison_key
from pipeline.evaluation.metrics.spec import percentile
from pipeline.evaluation.statistics.design import withheld
from pipeline.evaluation.statistics.records import outcome
from pipeline.evaluation.statistics.resampler import estimate
from pipeline.infra import seeds
from pipeline.infra.config.evaluation import cluster_of
from pipeline.scene.folds import category_of
from pipeline.method.names import MODEL_BASED, WITH_UNCERTAINTY, WU_POSES_ONLY

PAPER_SETTING = "biased_randomized"
EVENT = "wrong10_final"
DECADES = 1.0          # an interval of a log10 MGR difference wider than this gives no verdict
PAIRS = ((WU_POSES_ONLY, MODEL_BASED), (WITH_UNCERTAINTY, MODEL_BASED))
QUANTILES = (75, 95)


def values_by_target(cells, kept: Sequence[Mapping], labels: Sequence[str]) -> dict[str, dict[tuple[str, str], np.ndarray]]:
    """{method: {(target, scan): every final log10 MGR of its tracks and realizations in ``labels``}}."""
    out: dict[str, dict[tuple[str, str], list]] = {}
    want = set(labels)
    for c, k in zip(cells, kept):
        if c.variant != DEFAULT:
            continue
        for label, per in (k.get("final_mgr") or {}).items():
            if label in want:
                for m, v in per.items():
                    key = (str(c.target), str(getattr(c, "scan", "") or ""))
                    out.setdefault(m, {}).setdefault(key, []).append(np.asarray(v, float))
    return {m: {t: np.concatenate(v) for t, v in sorted(per.items())} for m, per in out.items()}


def _units(keys: Sequence[tuple[str, str]], cluster: str) -> dict[str, np.ndarray]:
    """{level: each (target, scan) block's unit code} of the levels with two units or more."""
    labels = {"targets": [t for t, _ in keys], "scans": [s for _, s in keys]}
    if cluster == "category":
        labels["categories"] = [category_of(t) for t, _ in keys]
    codes = {k: np.unique(np.asarray(v), return_inverse=True)[1].ravel() for k, v in labels.items()}
    return {k: c for k, c in codes.items() if c.max() >= 1}


def _weighted_quantiles(x: np.ndarray, block: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(B, len(QUANTILES)): the linear percentiles of ``x`` (sorted, each value's ``block``) repeated
    by the blocks' integer weights ``w`` (B, blocks): ``spec.percentile`` of the repeated values,
    its infinity rule included, without repeating them (NaN where a draw weighs nothing): the
    value between the two repeated entries the position falls on is their ``percentile``."""
    out = np.full((len(w), len(QUANTILES)), np.nan)
    for i, wb in enumerate(w):
        cum = np.cumsum(wb[block])
        n = int(cum[-1])
        if n == 0:
            continue
        h = (n - 1) * np.asarray(QUANTILES, float) / 100.0
        lo = np.floor(h)
        a = x[np.searchsorted(cum, lo, side="right")]
        b = x[np.searchsorted(cum, np.minimum(lo + 1, n - 1), side="right")]
        out[i] = [percentile([a[j], b[j]], 100 * (h[j] - lo[j])) for j in range(len(QUANTILES))]
    return out


def _draw_weights(units: Mapping[str, np.ndarray], levels: Mapping[str, int], cluster: str, n_boot: int,
                  seed) -> np.ndarray:
    """(B, blocks) integer weights of the (target, scan) blocks: a nested clustering (scan,
    category) draws its groups, then within each drawn group its targets; otherwise every level's
    units are drawn independently and a block weighs the product of its units' counts."""
    base = [int(x) for x in np.ravel(seed)]
    rng = seeds.stream(base[0], *base[1:], "mgr_percentiles")
    top = {"scan": "scans", "category": "categories"}.get(cluster)
    n = len(next(iter(units.values()))) if units else 0
    w = np.ones((n_boot, n), dtype=np.int64)
    if top in units and "targets" in units:
        g, t = units[top], units["targets"]
        members = [np.unique(t[g == k]) for k in range(levels[top])]
        tw = np.zeros((n_boot, levels["targets"]), dtype=np.int64)
        for i, slots in enumerate(rng.integers(0, levels[top], size=(n_boot, levels[top]))):
            for k in slots:
                np.add.at(tw[i], members[k], rng.multinomial(len(members[k]), np.full(len(members[k]),
                                                                                       1.0 / len(members[k]))))
        return tw[:, t]
    for k, c in units.items():
        w *= rng.multinomial(levels[k], np.full(levels[k], 1.0 / levels[k]), size=n_boot)[:, c]
    return w


def mgr_block(vals: Mapping[str, Mapping[tuple[str, str], np.ndarray]], n_boot: int, seed, labels: Sequence[str],
              cluster: str = "target") -> dict:
    """Per method the 75th and 95th percentiles of final log10 MGR over every track and realization,
    with 95 % CIs over the run's clustering (``cluster``: its units as the module says; withheld
    where a level has too few); per pair of ``PAIRS`` present, the difference of the 95th
    percentiles with its CI and verdict (None, with ``no_verdict``, where the CI spans > ``DECADES``
    or is withheld)."""
    methods = [m for m in dict.fromkeys(x for p in PAIRS for x in p) if vals.get(m)]
    if not methods:
        return {}
    keys = sorted(set.intersection(*(set(vals[m]) for m in methods)))
    units = _units(keys, cluster) if keys else {}
    levels = {k: int(c.max()) + 1 for k, c in units.items()}
    why = withheld(levels)
    w = _draw_weights(units, levels, cluster, int(n_boot), seed)
    out = {"settings": list(labels), "n_targets": len({t for t, _ in keys}), "levels": levels,
           "over": " x ".join(levels) + " (each unit with all its tracks and realizations)",
           "n_values": {m: int(sum(len(vals[m][t]) for t in keys)) for m in methods}, "methods": {}, "paired": {}}
    if why:
        out["withheld"] = why
    boot: dict[tuple[str, int], np.ndarray | None] = {}
    for m in methods:
        x = np.concatenate([vals[m][t] for t in keys])
        block = np.repeat(np.arange(len(keys)), [len(vals[m][t]) for t in keys])
        order = np.argsort(x, kind="stable")
        b = None if why else _weighted_quantiles(x[order], block[order], w)
        point = percentile(x, list(QUANTILES))
        for j, q in enumerate(QUANTILES):
            boot[m, q] = None if b is None else b[:, j]
            out["methods"].setdefault(m, {})[f"p{q}"] = estimate(float(point[j]), boot[m, q])
    for a, b in PAIRS:
        if a not in methods or b not in methods:
            continue
        with np.errstate(invalid="ignore"):
            d = None if why else boot[a, 95] - boot[b, 95]
        point = out["methods"][a]["p95"]["value"] - out["methods"][b]["p95"]["value"]
        est = estimate(point if not math.isnan(point) else math.nan, d)
        lo, hi = est["ci_low"], est["ci_high"]
        width = hi - lo if not (math.isnan(lo) or math.isnan(hi)) else math.nan
        entry = {"p95": est, "decades": width}
        if why:
            entry.update(verdict=None, no_verdict=why)
        elif not math.isfinite(width):
            entry.update(verdict=None, no_verdict="no bounded 95 % CI")
        elif width > DECADES:
            entry.update(verdict=None, no_verdict=f"the 95 % CI spans {width:.3g} decades")
        else:
            entry["verdict"] = outcome(lo, hi, False)
        out["paired"][comparison_key(a, b)] = entry
    return out


def paper_block(ev, table, cells, kept) -> dict:
    """summary.json's ``population.paper_55``: the §5.5 record and the MGR percentiles over every
    track (every setting, and the §5.5 setting where the run has it)."""
    out = comparison_record(ev, table, WU_POSES_ONLY, MODEL_BASED, EVENT, PAPER_SETTING)
    mgr = {}
    for scope in ("all", PAPER_SETTING):
        labels = setting_labels(ev, scope)
        if labels:
            mgr[scope] = mgr_block(values_by_target(cells, kept, labels), ev.bootstrap, ev.seed, labels,
                                   cluster_of(ev))
    return {**out, "event": "a wrong class at least 10 times as probable as the truth at the last step "
                            "(log10 MGR >= 1; ln MGR >= ln 10 = 2.303 on the paper's scale)",
            "mgr": mgr}
