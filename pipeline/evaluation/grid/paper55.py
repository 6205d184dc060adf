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
from resampling targets (each drawn target with all its tracks and realizations; the statistics
engine's draws), and the paired difference of the 95th percentiles on the same draws. Where that
interval spans more than one decade (or is unbounded) no verdict is given: an interval that wide
decides nothing about how far a wrong class beats the truth.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.grid.primary import comparison_record, setting_labels
from pipeline.evaluation.metrics.labels import comparison_key
from pipeline.evaluation.metrics.spec import percentile
from pipeline.evaluation.statistics.records import outcome
from pipeline.evaluation.statistics.resampler import draws, estimate
from pipeline.method.names import MODEL_BASED, WITH_UNCERTAINTY, WU_POSES_ONLY

PAPER_SETTING = "biased_randomized"
EVENT = "wrong10_final"
DECADES = 1.0          # an interval of a log10 MGR difference wider than this gives no verdict
PAIRS = ((WU_POSES_ONLY, MODEL_BASED), (WITH_UNCERTAINTY, MODEL_BASED))
QUANTILES = (75, 95)


def values_by_target(cells, kept: Sequence[Mapping], labels: Sequence[str]) -> dict[str, dict[str, np.ndarray]]:
    """{method: {target: every final log10 MGR of its tracks and realizations in ``labels``}}."""
    out: dict[str, dict[str, list]] = {}
    want = set(labels)
    for c, k in zip(cells, kept):
        if c.variant != DEFAULT:
            continue
        for label, per in (k.get("final_mgr") or {}).items():
            if label in want:
                for m, v in per.items():
                    out.setdefault(m, {}).setdefault(str(c.target), []).append(np.asarray(v, float))
    return {m: {t: np.concatenate(v) for t, v in sorted(per.items())} for m, per in out.items()}


def _pooled(per: Mapping[str, np.ndarray], targets: Sequence[str], idx: np.ndarray) -> np.ndarray:
    """The ``QUANTILES`` of the values of the targets ``idx`` (a target drawn twice counts twice)."""
    return percentile(np.concatenate([per[targets[i]] for i in idx]), list(QUANTILES))


def mgr_block(vals: Mapping[str, Mapping[str, np.ndarray]], n_boot: int, seed, labels: Sequence[str]) -> dict:
    """Per method the 75th and 95th percentiles of final log10 MGR over every track and realization,
    with 95 % CIs over targets; per pair of ``PAIRS`` present, the difference of the 95th
    percentiles with its CI and verdict (None, with ``no_verdict``, where the CI spans > ``DECADES``)."""
    methods = [m for m in dict.fromkeys(x for p in PAIRS for x in p) if vals.get(m)]
    if not methods:
        return {}
    targets = sorted(set.intersection(*(set(vals[m]) for m in methods)))
    T = len(targets)
    rs = draws([[1] * T], n_boot, seed) if T > 1 else None
    idx_all = np.arange(T)
    out = {"settings": list(labels), "n_targets": T, "over": "targets (each with all its tracks and realizations)",
           "n_values": {m: int(sum(len(vals[m][t]) for t in targets)) for m in methods}, "methods": {}, "paired": {}}
    boot: dict[tuple[str, int], np.ndarray | None] = {}
    for m in methods:
        b = None if rs is None else np.array([_pooled(vals[m], targets, rs.pt[i, 0]) for i in range(rs.n_boot)])
        point = _pooled(vals[m], targets, idx_all)
        for j, q in enumerate(QUANTILES):
            boot[m, q] = None if b is None else b[:, j]
            out["methods"].setdefault(m, {})[f"p{q}"] = estimate(float(point[j]), boot[m, q])
    for a, b in PAIRS:
        if a not in methods or b not in methods:
            continue
        with np.errstate(invalid="ignore"):
            d = None if rs is None else boot[a, 95] - boot[b, 95]
        point = out["methods"][a]["p95"]["value"] - out["methods"][b]["p95"]["value"]
        est = estimate(point if not math.isnan(point) else math.nan, d)
        lo, hi = est["ci_low"], est["ci_high"]
        width = hi - lo if not (math.isnan(lo) or math.isnan(hi)) else math.nan
        entry = {"p95": est, "decades": width}
        if not math.isfinite(width):
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
            mgr[scope] = mgr_block(values_by_target(cells, kept, labels), ev.bootstrap, ev.seed, labels)
    return {**out, "event": "a wrong class at least 10 times as probable as the truth at the last step "
                            "(log10 MGR >= 1; ln MGR >= ln 10 = 2.303 on the paper's scale)",
            "mgr": mgr}
