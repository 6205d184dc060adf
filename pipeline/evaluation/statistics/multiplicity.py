"""Holm's step-down over the declared primary family (``metrics.labels.in_primary_family``),
familywise 95 %.

The one interval rule decides every verdict, so Holm is done by widening intervals, step by step:
with m records of the family still open, each one's interval is taken at level 1 - 0.05/m; if some
exclude 0, the one with the smallest p-value among them is rejected (its adjusted interval is that
one) and m drops by one; when none does, every open record keeps its interval at that level and is
"not distinguishable". A record's interval and p-value are one statistic: a mean of one run's tracks
carries its t statistic from the design (``design.TStat``: value +- q se at any level, q the larger
of t_df's quantile and its wild cluster bootstrap's, and p the larger of the two p-values, the
smallest level whose interval excludes 0), so an adjusted verdict rests on the variance estimate
and the t's own tails (t_df alone let the familywise error reach 7 % where track noise dominates:
docs/calibration.md), not on the few draws in a percentile bootstrap's tails. A statistic without one
(a median, the pooled ECE, a seed pool) keeps the percentile interval of its draws and the
bootstrap p-value (two-sided, 2 min(P(d <= 0), P(d >= 0)) with the +1 correction). Since both kinds
of interval nest as the level grows, this is Holm's procedure, and the adjusted outcome is
``records.outcome`` of the adjusted interval (never a label its interval contradicts). A record
whose interval is withheld (too few clusters: ``design.withheld``) was never tested: it stays out
of the family (no p, no adjusted interval) and does not count in its size. The declared primary comparison (``evaluate.primary``) is tested
alone; where a block's cells are its own, ``exclude`` leaves it out of the family.
"""
from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence

import numpy as np

from pipeline.evaluation.metrics.labels import in_primary_family
from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.design import TStat
from pipeline.evaluation.statistics.resampler import LEVEL, estimate
from pipeline.infra.outputs import number

ALPHA = 1.0 - LEVEL


def bootstrap_p(draws: np.ndarray | None) -> float:
    """Two-sided bootstrap p-value of 0 from the draws of a difference: 2 min((1 + #{d <= 0}),
    (1 + #{d >= 0})) / (B + 1), at most 1; 1 without draws or with an undefined draw."""
    if draws is None:
        return 1.0
    d = np.asarray(draws, float)
    if d.size == 0 or np.isnan(d).any():
        return 1.0
    B = d.size
    return float(min(1.0, 2 * min(1 + np.sum(d <= 0), 1 + np.sum(d >= 0)) / (B + 1)))


def holm_p(p: Sequence[float]) -> list[float]:
    """Holm-adjusted p-values: in increasing order, max over the earlier ones of min(1, (m - i) p_(i))."""
    order = np.argsort(np.asarray(p, float), kind="stable")
    m, out, run = len(p), [1.0] * len(p), 0.0
    for i, j in enumerate(order):
        run = max(run, min(1.0, (m - i) * float(p[j])))
        out[j] = run
    return out


def holm(records: list[dict], draws: Mapping[tuple[str, str], np.ndarray | None], family=None,
         exclude: Collection[tuple[str, str]] = ()) -> None:
    """Add the Holm fields to each record of the primary family (in place; ``family``: another
    predicate of (comparison, primary), e.g. the class-level contrast's own): ``p`` and ``p_holm``,
    ``level_holm`` (the interval's level), ``lo_holm``/``hi_holm`` (null: unbounded) and
    ``outcome_holm``, and ``family`` (its size). ``draws``: {(comparison, metric): the draws of
    the record's difference} (missing or None: no interval, never rejected). ``exclude``: the
    (comparison, metric) of the declared primary comparison where this block's cells are its own:
    it is tested alone at 0.05 (``grid.primary``), so it leaves the exploratory family and is
    marked ``declared``."""
    for r in records:
        if (r["comparison"], r["metric"]) in exclude:
            r["declared"] = True
    fam = [r for r in records if (family or in_primary_family)(r["comparison"], r.get("primary"))
           and not r.get("declared") and not r.get("withheld")]
    if not fam:
        return
    d = [draws.get((r["comparison"], r["metric"])) for r in fam]
    p = [x.p() if isinstance(x, TStat) else bootstrap_p(x) for x in d]
    for r, pi, pa in zip(fam, p, holm_p(p)):
        r.update(p=pi, p_holm=pa, family=len(fam))
    open_ = list(range(len(fam)))
    while open_:
        level = 1.0 - ALPHA / len(open_)
        ests = {i: _at(number(fam[i]["value"]), d[i], level) for i in open_}
        out = {i: REC.outcome(e["ci_low"], e["ci_high"], fam[i]["better"] == "higher") if e else "not distinguishable"
               for i, e in ests.items()}
        firm = [i for i in open_ if out[i] != "not distinguishable"]
        done = [min(firm, key=lambda i: (p[i], i))] if firm else list(open_)
        for i in done:
            _set(fam[i], level, ests[i], out[i])
            open_.remove(i)


def _at(value: float, d, level: float) -> dict | None:
    """The record's interval at ``level``: its t interval (a ``TStat``; none where withheld), or the
    percentile interval of its draws; None without either."""
    if isinstance(d, TStat):
        e = d.estimate(level)
        return None if math.isnan(e["ci_low"]) else e
    return estimate(value, d, level) if d is not None else None


def _set(rec: dict, level: float, est: Mapping | None, outcome: str) -> None:
    lo, hi = (number(est["ci_low"], -math.inf), number(est["ci_high"], math.inf)) if est else (math.nan, math.nan)
    rec.update(level_holm=level, lo_holm=lo, hi_holm=hi, outcome_holm=outcome)


def adjusted(rec: Mapping) -> str:
    """The verdict the bottom line and the scorecard read: the Holm-adjusted one where the record
    is in the primary family, else its own (the declared primary comparison's: tested alone)."""
    return str(rec.get("outcome_holm") or rec["outcome"])
