"""Intervals from the design: the multiway cluster-robust variance of a population's mean statistic
and its t interval (Cameron, Gelbach & Miller 2011), what every mean-pooled value and paired
difference of one run rests on (``engine.block``; measured by ``pipeline.evaluation.calibration``).

The pooled statistic is linear in the track values: theta = sum_i w_i y_i (``w`` the leaf weights of
the point value: each target weighs the same, each of its tracks the same; a group clustering
(scan, category) puts its groups on top). Each track lies in one unit of every clustering level the
design has (targets; scans where the cells name two or more; categories where they are the
clustering). With u_i = w_i (y_i - theta), one level's variance is V_g = c_g sum_units (sum_{i in
unit} u_i)^2, c_g = G/(G - 1) over its G units; the design's variance is the inclusion-exclusion of
the levels and their intersections (two levels: V_obj + V_scan - V_obj∩scan), so the track noise,
which every level sees, is counted once (the pigeonhole bootstrap counted it twice). Where that sum
is not positive, the largest one-level variance stands in (CGM's rule). The interval is
theta ± t_{1 - a/2, df} sqrt(V), df = min(G_min - 1, the Bell-McCaffrey degrees of freedom of V's
quadratic form under equal independent track noise: ``design_df``), G_min the fewest units of any
level (one level of balanced units: G - 1, the classical t interval).

A level with fewer than ``MIN_CLUSTERS`` units has no calibrated interval (its variance term rests
on too few units: docs/calibration.md measures 2-cluster designs covering 55-70 %): the estimate then
carries no interval and says why (``withheld``), and no verdict follows from it.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import sparse
from scipy.stats import t as student_t

from pipeline.evaluation.statistics import wild
from pipeline.evaluation.statistics.resampler import LEVEL

MIN_CLUSTERS = 8   # fewest units a clustering level needs for an interval (docs/calibration.md: 5-6 cover 89-93 %)
INTERVAL = "cluster-robust t, wild bootstrap tails"   # the engine's: t_df or the wild bootstrap-t, the wider (``wild``)
T_INTERVAL = "cluster-robust t"         # the same t against t_df (the previous engine; the calibration suite's baseline)


@dataclass(frozen=True)
class Layout:
    """A population's leaves (its tracks): ``weights`` (N,) of the point statistic (summing to 1)
    and, per clustering level ("targets", "scans", "categories"), each leaf's unit code (N,)."""
    weights: np.ndarray
    labels: Mapping[str, np.ndarray]

    @cached_property
    def terms(self) -> list:
        """``one_way_terms``, once per layout."""
        return one_way_terms(self)

    @cached_property
    def wild_plan(self):
        """``wild.plan``, once per layout."""
        return wild.plan(self)

    @cached_property
    def df(self) -> float:
        """``design_df``, once per layout."""
        return design_df(self)

    def levels(self) -> dict[str, int]:
        """{level: its number of units}, for the levels with two units or more."""
        out = {k: int(len(np.unique(v))) for k, v in self.labels.items()}
        return {k: g for k, g in out.items() if g > 1}


def _indicator(codes: np.ndarray) -> tuple[sparse.csr_matrix, int]:
    _, inv = np.unique(codes, axis=0, return_inverse=True)
    inv = np.asarray(inv).ravel()
    G = int(inv.max()) + 1
    return sparse.csr_matrix((np.ones(len(inv)), (np.arange(len(inv)), inv)), shape=(len(inv), G)), G


def _terms(layout: Layout) -> list[tuple[int, sparse.csr_matrix, int]]:
    """The inclusion-exclusion terms: (sign, unit indicator (N, G), G) of every level and intersection."""
    names = list(layout.levels())
    out = []
    for r in range(1, len(names) + 1):
        for subset in itertools.combinations(names, r):
            M, G = _indicator(np.stack([layout.labels[k] for k in subset], axis=1))
            if G >= 2:
                out.append(((-1) ** (r + 1), M, G))
    return out


def design_df(layout: Layout) -> float:
    """The degrees of freedom of V for this layout: (tr A)^2 / tr(A^2) of its quadratic form V = e'Ae
    under independent equal track noise (Bell & McCaffrey 2002), at most G_min - 1. The subtracted
    terms add noise to V, so V has fewer degrees of freedom than its smallest level: t_{G_min - 1}
    rejected 6 % a test and 11 % familywise on 12 targets x 8 scans with track noise dominant
    (docs/calibration.md). One level of G balanced units: G - 1."""
    levels = layout.levels()
    if not levels:
        return math.nan
    w = np.asarray(layout.weights, float)
    k = float(w @ w)
    terms = _terms(layout)
    # M_s' P P' M_t = M_s' diag(w^2) M_t + low rank, P = diag(w) (I - 1 w'): u = P y
    parts = []
    for sign, M, G in terms:
        a, b = np.asarray(M.T @ w).ravel(), np.asarray(M.T @ (w * w)).ravel()
        parts.append((sign, G / (G - 1), M, a, b))
    tr, tr2 = 0.0, 0.0
    for s1, c1, M1, a1, b1 in parts:
        X = (M1.T.multiply(w * w)) @ M1
        tr += s1 * c1 * (X.diagonal().sum() - 2 * a1 @ b1 + k * a1 @ a1)
        for s2, c2, M2, a2, b2 in parts:
            X = ((M1.T.multiply(w * w)) @ M2).tocsr()
            P, Q = [-a1, -b1, k * a1], [b2, a2, a2]
            fro = X.multiply(X).sum() + 2 * sum(p @ (X @ q) for p, q in zip(P, Q)) \
                + sum((P[i] @ P[j]) * (Q[i] @ Q[j]) for i in range(3) for j in range(3))
            tr2 += s1 * s2 * c1 * c2 * fro
    nu = tr * tr / tr2 if tr2 > 0 else math.inf
    return float(max(1.0, min(nu, min(levels.values()) - 1)))


def one_way_terms(layout: Layout) -> list[tuple[int, sparse.csr_matrix, int, bool]]:
    """``_terms`` with whether each is a one-level term (those come first)."""
    n = len(layout.levels())
    return [(s, M, G, i < n) for i, (s, M, G) in enumerate(_terms(layout))]


def variance(values: np.ndarray, layout: Layout) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """(theta (R,), V (R,), levels) of R replications' leaf values (R, N) at once."""
    y = np.atleast_2d(np.asarray(values, float))
    w = np.asarray(layout.weights, float)
    theta = y @ w
    u = (y - theta[:, None]) * w[None, :]
    levels = layout.levels()
    V = np.zeros(len(y))
    one_way = []
    for sign, M, G, _ in layout.terms:
        sums = np.asarray(M.T @ u.T).T                                     # (R, G): each unit's sum
        v = G / (G - 1) * (sums ** 2).sum(axis=1)
        V += sign * v
        if sign > 0 and len(one_way) < len(levels):
            one_way.append(v)
    if one_way:
        V = np.where(V > 0, V, np.max(one_way, axis=0))
    return theta, V, levels


def withheld(levels: Mapping[str, int], n_levels: Mapping[str, int] | None = None) -> str | None:
    """Why no calibrated interval exists (a level with too few units, or no level with two), else None."""
    if not levels:
        return "one unit on every level: nothing to vary over"
    few = {k: g for k, g in levels.items() if g < MIN_CLUSTERS}
    if few:
        what = ", ".join(f"{g} {k}" for k, g in few.items())
        return (f"{what}: a calibrated interval needs at least {MIN_CLUSTERS} units of every level the design "
                "varies over (docs/calibration.md)")
    return None


def t_interval(values: np.ndarray, layout: Layout, level: float = LEVEL, n_boot: int = 0,
               seed=0) -> dict[str, np.ndarray]:
    """Arrays (R,) of "value", "se", "df", "ci_low", "ci_high" (NaN where withheld) and "p" (two-sided
    p of 0; NaN where withheld) for R replications' leaf values (R, N); "withheld": the reason or None.
    ``n_boot`` > 0: the t statistic's quantile and p-value are the larger of t_df's and its wild
    cluster bootstrap's (``wild``: B draws, "ref" (R, B) |t*|), else t_df's."""
    theta, V, levels = variance(values, layout)
    se = np.sqrt(np.maximum(V, 0.0))
    why = withheld(levels)
    df = np.full_like(theta, layout.df)
    if why is not None:
        nan = np.full_like(theta, np.nan)
        return {"value": theta, "se": se, "df": df, "ci_low": nan, "ci_high": nan, "p": nan, "withheld": why,
                "levels": levels, "ref": None}
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(se > 0, np.abs(theta) / se, np.where(theta == 0, 0.0, np.inf))
    ref, q, p = None, student_t.ppf(0.5 + level / 2, df), 2 * student_t.sf(z, df)
    if n_boot:   # the wider of the two references at every level (``wild``: why)
        ref = wild.abs_t(values, layout, n_boot, seed)
        q, p = np.maximum(q, wild.quantile(ref, level)), np.maximum(p, wild.p_value(ref, z))
    return {"value": theta, "se": se, "df": df, "ci_low": theta - q * se, "ci_high": theta + q * se, "p": p,
            "withheld": None, "levels": levels, "ref": ref}


@dataclass(frozen=True)
class TStat:
    """One estimate's t statistic and its reference: what the Holm steps read at any level
    (``multiplicity``). ``ref``: its wild bootstrap |t*| draws (``wild``), else t_df."""
    value: float
    se: float
    df: float
    withheld: str | None = None
    ref: np.ndarray | None = field(default=None, compare=False, repr=False)

    def p(self) -> float:
        if self.withheld or not math.isfinite(self.se):
            return 1.0
        if self.se <= 0:
            return 0.0 if self.value != 0 else 1.0
        t = abs(self.value) / self.se
        p = float(2 * student_t.sf(t, self.df))
        return max(p, float(wild.p_value(self.ref, t))) if self.ref is not None else p

    def q(self, level: float = LEVEL) -> float:
        """The half-width's multiplier at ``level``: the quantile of |t| under its reference (with a
        wild bootstrap, the larger of its quantile and t_df's: ``wild``)."""
        q = float(student_t.ppf(0.5 + level / 2, self.df))
        return max(q, float(wild.quantile(self.ref, level))) if self.ref is not None else q

    def estimate(self, level: float = LEVEL) -> dict[str, float]:
        if self.withheld or not math.isfinite(self.se):
            return {"value": self.value, "ci_low": math.nan, "ci_high": math.nan}
        h = self.q(level) * self.se if self.se > 0 else 0.0
        return {"value": self.value, "ci_low": self.value - h, "ci_high": self.value + h}


def estimate(values: np.ndarray, layout: Layout, clamp: tuple[float, float] | None = None, n_boot: int = 0,
             seed=0) -> tuple[dict, TStat]:
    """One population's estimate {"value", "ci_low", "ci_high", "se", "df", "interval", "levels",
    "withheld"?} of its leaf values (N,), and its ``TStat``; ``clamp``: the metric's range (a
    pooled value's interval never leaves it); ``n_boot``, ``seed``: the wild bootstrap's draws
    (0: t_df, the previous engine's reference)."""
    r = t_interval(np.asarray(values, float)[None, :], layout, n_boot=n_boot, seed=seed)
    value, se, df = float(r["value"][0]), float(r["se"][0]), float(r["df"][0])
    lo, hi = float(r["ci_low"][0]), float(r["ci_high"][0])
    if clamp is not None and not math.isnan(lo):
        lo, hi = max(lo, clamp[0]), min(hi, clamp[1])
    est = {"value": value, "ci_low": lo, "ci_high": hi, "se": se, "df": df,
           "interval": INTERVAL if n_boot else T_INTERVAL, "levels": dict(r["levels"])}
    if r["withheld"]:
        est["withheld"] = r["withheld"]
    ref = None if r["ref"] is None else r["ref"][0]
    return est, TStat(value, se, df, r["withheld"], ref)
