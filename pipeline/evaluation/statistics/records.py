"""Verdict records: one structured record per (comparison, metric), and the one outcome rule.

A record is data, never prose: ``reports.shared.records`` renders the sentences. Fields
(docs/design.md, "Statistics"):

- ``comparison`` ("method-baseline"), ``method``, ``baseline``, ``metric``;
- ``pooling``: how targets pool the metric (``spec.pool_of``: "mean", "median", "pooled
  posteriors"); ``value`` is that statistic of the paired differences, ``lo``/``hi`` its 95 %
  percentile interval (+-inf: unbounded on that side, written as null; NaN: no interval);
- ``over``: the levels the interval resamples (["targets", "tracks"]; a study adds "seeds";
  ``hierarchy.OVER`` per clustering); ``cluster``: the design's independent unit on top
  (``evaluate.statistics.cluster``: target, scan, category, crossed); ``n``: the units of each
  level ({"targets": 6, "tracks": 48, "cells": 192, ...});
- ``better``: "higher" | "lower"; ``outcome``: ``outcome(lo, hi, better)``; ``primary``: the
  metric is one of ``evaluate.primary_metrics`` (the rest are exploratory);
- ``interval``: how the interval was made: "cluster-robust t, wild bootstrap tails" (``design``: a
  mean of one run's tracks; with ``se``, ``df`` and ``levels``, the units of each level it varies over) or
  "percentile bootstrap" (a median, an infinite value, the pooled ECE, a seed pool); ``withheld``:
  why there is no interval where a level the run clusters on has too few units for a calibrated one
  (``design.withheld``; the same rule for a mean's t interval and a bootstrap one): no verdict,
  ``outcome`` "withheld", lo/hi NaN, and the record stays out of the Holm family;
- optional: ``wins``/``losses`` (shares of ``unit``: cells or targets), the leave-one-target-out
  range ``loto_min``/``loto_max`` and ``loto_flips``, ``ceiling_cells``/``floor_cells``;
- the primary family only (``metrics.labels.in_primary_family``; ``multiplicity.holm``):
  ``family`` (its size), ``p``/``p_holm`` (the record's p-value: from its t statistic, else from
  its draws; Holm-adjusted), ``level_holm``,
  ``lo_holm``/``hi_holm`` (the interval widened to its Holm step) and ``outcome_holm``.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pipeline.infra.outputs import number

OUTCOMES = ("better", "worse", "not distinguishable", "withheld")
WITHHELD = "withheld"   # no interval, hence no verdict (the record's ``withheld`` says why)


def outcome(lo: float | None, hi: float | None, higher_is_better: bool) -> str:
    """The one outcome rule: "better" when the 95 % interval of method - baseline lies wholly on
    the good side of 0, "worse" on the bad side, else (or without an interval) "not distinguishable".
    ``lo`` None is -inf, ``hi`` None is +inf (an unbounded end); a non-number is no interval."""
    a, b = number(lo, -math.inf), number(hi, math.inf)
    if math.isnan(a) or math.isnan(b) or (math.isinf(a) and math.isinf(b)):
        return "not distinguishable"
    if a > 0:
        return "better" if higher_is_better else "worse"
    if b < 0:
        return "worse" if higher_is_better else "better"
    return "not distinguishable"


def record(comparison: str, metric: str, est: Mapping[str, float], *, pooling: str, better: str,
           over: list[str], n: Mapping[str, int], primary: bool, **extra: Any) -> dict:
    """One record from an estimate {"value", "ci_low", "ci_high"} of method - baseline."""
    method, baseline = comparison.split("-", 1)
    lo, hi = number(est["ci_low"], -math.inf), number(est["ci_high"], math.inf)   # null: unbounded (JSON)
    return {"comparison": comparison, "method": method, "baseline": baseline, "metric": metric,
            "pooling": pooling, "value": number(est["value"]), "lo": lo, "hi": hi,
            "unbounded": bool(math.isinf(lo) or math.isinf(hi)), "over": list(over),
            "n": {k: int(v) for k, v in n.items()}, "better": better,
            "outcome": WITHHELD if extra.get("withheld") else outcome(lo, hi, better == "higher"),
            "primary": bool(primary), **extra}


def consistent(rec: Mapping[str, Any]) -> bool:
    """The record's label agrees with its interval (the outcome rule) and its value lies in it."""
    if rec.get("outcome") not in OUTCOMES or rec.get("better") not in ("higher", "lower"):
        return False
    if rec["outcome"] == WITHHELD or rec.get("withheld"):
        return rec["outcome"] == WITHHELD and bool(rec.get("withheld"))   # lo/hi: NaN, null in JSON
    if rec["outcome"] != outcome(rec.get("lo"), rec.get("hi"), rec["better"] == "higher"):
        return False
    v, lo, hi = rec.get("value"), rec.get("lo"), rec.get("hi")
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return True
    a, b = number(lo, -math.inf), number(hi, math.inf)
    return math.isnan(a) or math.isnan(b) or a <= float(v) <= b


EQUIVALENCE_OUTCOMES = ("equivalent", "different", "not distinguishable")


def equivalence(lo: float | None, hi: float | None, margin: float) -> str:
    """The equivalence reading of an interval of method - baseline ("similar", within ±``margin``):
    "equivalent" when the whole 95 % interval lies inside [-margin, margin], "different" when it
    lies wholly outside it (beyond +margin or below -margin), else (or without an interval, or with
    an unbounded end) "not distinguishable". ``lo``/``hi`` None are unbounded ends."""
    a, b = number(lo, -math.inf), number(hi, math.inf)
    m = float(margin)
    if math.isnan(a) or math.isnan(b) or math.isnan(m) or m < 0:
        return "not distinguishable"
    if -m <= a and b <= m:
        return "equivalent"
    if a > m or b < -m:
        return "different"
    return "not distinguishable"
