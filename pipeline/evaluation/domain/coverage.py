"""The 95 % CI of a variance kind's pooled coverage (the share of standardized residuals with
|z| <= 1.96), clustered by the run's units.

The residuals of one crop's components, of one instance and of one scan are correlated, so the
interval resamples the run's units, never the residuals: instances (targets), and scans where the
run clusters on them (``evaluate.statistics.cluster``, ``config.cluster_of``), with the project's
resamplers (``resampler.draws``: the nested levels; ``crossed.crossed_draws``: instances and scans
crossed). The coverage is a ratio of sums (inside / total), so the residuals are first summed per
(scan, instance) cluster and each draw re-weights those sums: exact, and cheap on 622,000
residuals. Every kind of one table reads the same draws. A level with fewer than
``design.MIN_CLUSTERS`` units gives no interval and says why (``design.withheld``), as every
pooled statistic of the run does.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from pipeline.evaluation.domain.fit import Z95   # the same |z| bound as the share itself (fit.fit_summary)
from pipeline.evaluation.statistics.crossed import crossed_draws
from pipeline.evaluation.statistics.design import withheld as design_withheld
from pipeline.evaluation.statistics.resampler import estimate
from pipeline.evaluation.statistics.resampler import draws as nested_draws
from pipeline.infra.seeds import key

# what each clustering's interval resamples (a row's ``coverage95_over``)
OVER = {"target": "instances, then the scans each was seen in", "scan": "scans, then the instances in each",
        "crossed": "instances and scans, crossed"}


def cluster_sums(table: pd.DataFrame, z_by_kind: Mapping[str, np.ndarray]) -> tuple[list, dict]:
    """([(scan, instance)] sorted, {kind: (inside counts (G,), finite totals (G,))}): each kind's
    residuals summed per (scan, instance) cluster (a non-finite z counts in neither, as in
    ``fit.fit_summary``)."""
    code, uniq = pd.factorize(table["scan"].astype(str) + "\x00" + table["instance"].astype(str), sort=True)
    G = len(uniq)
    out = {}
    for kind, z in z_by_kind.items():
        z = np.asarray(z, float)
        ok = np.isfinite(z)
        out[kind] = (np.bincount(code, weights=(ok & (np.abs(np.where(ok, z, 0.0)) <= Z95)), minlength=G),
                     np.bincount(code, weights=ok, minlength=G).astype(float))
    return [tuple(u.split("\x00", 1)) for u in uniq], out


def _weights(clusters: list, cluster: str, n_boot: int, seed) -> tuple[np.ndarray, str]:
    """(B, G): each (scan, instance) cluster's weight in each draw, and what the draws resample."""
    scans = sorted({s for s, _ in clusters})
    insts = sorted({i for _, i in clusters})
    G = len(clusters)
    if cluster == "crossed" and len(scans) > 1:
        si, ii = {s: k for k, s in enumerate(scans)}, {i: k for k, i in enumerate(insts)}
        rs = crossed_draws([[si[s] for s, i in clusters if i == inst] for inst in insts], n_boot, seed)
        return (rs.m_obj[:, [ii[i] for _, i in clusters]] * rs.m_scan[:, [si[s] for s, _ in clusters]]).astype(float), \
            OVER["crossed"]
    top, inner, over = ((scans, lambda c: c[0], "scan") if cluster in ("scan", "crossed") and len(scans) > 1
                        else (insts, lambda c: c[1], "target"))
    groups = [[g for g in range(G) if inner(clusters[g]) == u] for u in top]    # clusters sorted: stable order
    if over == "scan":   # scans (seed level) -> their instances (targets), one leaf each
        rs = nested_draws([[1] * len(m) for m in groups], n_boot, seed)
        leaf = np.full(rs.shape, -1, dtype=np.int64)
        for s, m in enumerate(groups):
            leaf[s, : len(m), 0] = m
    else:                # instances (targets) -> the scans each was seen in (tracks)
        rs = nested_draws([[len(m) for m in groups]], n_boot, seed)
        leaf = np.full(rs.shape, -1, dtype=np.int64)
        for t, m in enumerate(groups):
            leaf[0, t, : len(m)] = m
    idx = leaf[rs.ps[..., None], rs.pt]                                          # (B, S, T, W)
    B = rs.n_boot
    w = np.zeros((B, G))
    used = (idx >= 0) & (rs.counts > 0)
    np.add.at(w, (np.broadcast_to(np.arange(B)[:, None, None, None], idx.shape)[used], idx[used]), rs.counts[used])
    return w, OVER[over]


def coverage_cis(table: pd.DataFrame, z_by_kind: Mapping[str, np.ndarray], cluster: str, n_boot: int,
                 seed: int) -> dict[str, dict]:
    """{kind: {"coverage95_ci": [lo, hi] or None, "coverage95_over": what it resamples,
    "coverage95_units": {"instances": n, "scans": n}, "coverage95_withheld": why no CI (only then)}}:
    the percentile interval of each kind's pooled coverage over the run's units (``cluster``:
    ``evaluate.statistics.cluster``; "category" resamples instances, the test domain's units)."""
    clusters, sums = cluster_sums(table, z_by_kind)
    scans = {s for s, _ in clusters}
    levels = {"instances": len({i for _, i in clusters})}
    on_scans = cluster in ("scan", "crossed") and len(scans) > 1
    if on_scans:
        levels["scans"] = len(scans)
    why = design_withheld({k: g for k, g in levels.items() if g > 1})
    w, over = (None, OVER["scan" if on_scans and cluster == "scan" else "crossed" if on_scans else "target"]) \
        if why or not clusters else _weights(clusters, cluster, n_boot, key(seed, "domain fit", "coverage95"))
    out = {}
    for kind, (k, n) in sums.items():
        entry = {"coverage95_ci": None, "coverage95_over": over, "coverage95_units": dict(levels)}
        if why:
            entry["coverage95_withheld"] = why
        elif n.sum() > 0:
            with np.errstate(invalid="ignore", divide="ignore"):
                est = estimate(k.sum() / n.sum(), (w @ k) / (w @ n))
            if np.isfinite([est["ci_low"], est["ci_high"]]).all():
                entry["coverage95_ci"] = [est["ci_low"], est["ci_high"]]
            else:   # a draw that kept no residual (crossed: no drawn instance in a drawn scan): undefined
                entry["coverage95_withheld"] = "a resample kept no residual: the interval is undefined"
        out[kind] = entry
    return out
