"""Power from variance components: how likely the declared primary comparison (``evaluate.primary``)
is to detect a stated effect, and what population would make it 80 %.

The paired-difference table of the primary comparison (``grid.primary.paired_table``: one row per
(object, scan, track), method - baseline averaged over the declared settings) is read as a crossed
random-effects design d = mu + a_object + b_scan + (ab)_cell + e_track. Moment estimators (Gao &
Owen's U-statistics on cell means; no model fit):

- track: the pooled within-cell variance of the tracks (cells with 2+ tracks);
- U_o, U_s, U_n: half the mean squared difference of two cell means sharing the object (other
  scan), sharing the scan (other object), sharing neither; with h the mean of 1/n over cells
  their expectations are sb + sab + st h, sa + sab + st h, sa + sb + sab + st h, so
  object = U_n - U_o, scan = U_n - U_s, interaction = U_o + U_s - U_n - track h (each floored at 0).

A design with one scan cannot separate the scan term (it is taken as 0 and the page says so: the
power is then optimistic); one object per scan likewise the object term. The variance of the pooled
mean difference with I objects, J scans, C cells and n tracks per cell is then
object/I + scan/J + interaction/C + track/(C n); the test is two-sided at alpha = 0.05 (the declared
comparison is not adjusted), power = P(|Z| > z_(1-alpha/2)) with Z ~ N(effect/SE, 1). More objects keep
each object's scans (C grows with I), more scans each scan's objects (C grows with J). The track
term holds the localization realizations too: more realizations shrink only that part of it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd
from scipy.stats import chi2, norm

EFFECT = 0.05      # the stated effect the power is for (a difference of 0.05 on the primary metric)
POWER = 0.80
ALPHA = 0.05       # two-sided; the declared primary comparison is not adjusted for multiplicity
MAX_TRACKS = 1000  # evaluate.tracks_per_target's bound: a need beyond it is not a config change


def _half_mean_sq(groups: list[np.ndarray]) -> tuple[float, int]:
    """(sum over groups of sum over pairs (y_a - y_b)^2 / 2, number of pairs)."""
    s, n = 0.0, 0
    for y in groups:
        k = len(y)
        if k > 1:
            s += (k * float(np.sum(y * y)) - float(np.sum(y)) ** 2) / 2.0
            n += k * (k - 1) // 2
    return s, n


def components(d: pd.DataFrame) -> dict:
    """The variance components of the paired differences ``d`` (columns target, scan, track, d):
    object, scan, interaction, track (None: not estimable here), the design's counts and notes."""
    cells = d.groupby(["target", "scan"], sort=True)["d"].agg(["mean", "var", "count"]).reset_index()
    I, J, C = int(cells["target"].nunique()), int(cells["scan"].nunique()), len(cells)
    multi = cells[cells["count"] > 1]
    dof = float((multi["count"] - 1).sum())
    track = float(((multi["count"] - 1) * multi["var"]).sum() / dof) if dof > 0 else None
    h = float(np.mean(1.0 / cells["count"])) if C else math.nan
    y = cells["mean"].to_numpy(float)
    so, no = _half_mean_sq([g["mean"].to_numpy(float) for _, g in cells.groupby("target")])
    ss, ns = _half_mean_sq([g["mean"].to_numpy(float) for _, g in cells.groupby("scan")])
    sa, na = _half_mean_sq([y])
    nn = na - no - ns
    Uo, Us = (so / no if no else None), (ss / ns if ns else None)
    Un = (sa - so - ss) / nn if nn > 0 else None
    noise = (track or 0.0) * h
    notes = []
    if track is None:
        notes.append("no cell holds two tracks: the track term is not separable from the interaction")
    obj = scan = inter = None
    if Un is not None and Uo is not None and Us is not None:
        obj, scan = max(0.0, Un - Uo), max(0.0, Un - Us)
        inter = max(0.0, Uo + Us - Un - noise)
    elif Us is not None:   # one scan (or no two cells sharing an object): object and interaction together
        obj, scan, inter = max(0.0, Us - noise), 0.0, 0.0
        notes.append("one scan per object: the scan term is not estimable (taken as 0: the power is optimistic) "
                     "and the object term holds the interaction")
    elif Uo is not None:
        obj, scan, inter = 0.0, max(0.0, Uo - noise), 0.0
        notes.append("one object per scan: the object term is not estimable (taken as 0)")
    elif C == 1 and len(d) > 1:
        obj = scan = inter = 0.0
        notes.append("one (object, scan) cell: only the track term is estimable")
    return {"object": obj, "scan": scan, "interaction": inter, "track": track,
            "n_objects": I, "n_scans": J, "n_cells": C, "n_tracks": int(len(d)),
            "tracks_per_cell": float(len(d) / C) if C else 0.0, "notes": notes}


def variance(comp: Mapping, I: float, J: float, C: float, n: float) -> float:
    """The variance of the pooled mean difference at I objects, J scans, C cells, n tracks per cell."""
    return (comp["object"] / I + comp["scan"] / J + comp["interaction"] / C
            + (comp["track"] or 0.0) / (C * n))


def power_at(se: float, effect: float = EFFECT, alpha: float = ALPHA) -> float:
    """Two-sided power of a z-test at standard error ``se`` for a true difference ``effect``."""
    if not se > 0:
        return 1.0
    z = norm.ppf(1 - alpha / 2)
    return float(norm.cdf(effect / se - z) + norm.cdf(-effect / se - z))


def needed_variance(effect: float = EFFECT, power: float = POWER, alpha: float = ALPHA) -> float:
    return (effect / (norm.ppf(1 - alpha / 2) + norm.ppf(power))) ** 2


def _tracks_for(comp: Mapping, I: float, J: float, C: float, target: float) -> float | None:
    """Tracks per cell that bring the variance to ``target`` at I, J, C; None when none do."""
    rest = target - (comp["object"] / I + comp["scan"] / J + comp["interaction"] / C)
    if rest <= 0:
        return None
    if not comp["track"]:
        return 1.0
    return comp["track"] / (C * rest)


def _units_for(comp: Mapping, term: str, others: float, target: float) -> int | None:
    """Objects (or scans) that bring the variance to ``target`` when every other term stays at
    ``others`` and the cells grow with the units; None when none do."""
    per = comp[term] + comp["interaction_per_unit"] + comp["track_per_unit"]
    room = target - others
    if room <= 0:
        return None
    return int(math.ceil(per / room - 1e-9))


def power_interval(v_now: float, df: float, effect: float = EFFECT, level: float = 0.95) -> dict:
    """{"ci_low", "ci_high", "df", "over"} of the power now: the variance of the pooled difference
    read as a scaled chi-square with the design's degrees of freedom ``df`` (Satterthwaite's
    approximation, the df the engine's interval uses: ``design.design_df``), its ``level`` interval
    [v df / chi2_(1+level)/2, v df / chi2_(1-level)/2] mapped through the power (which falls as the
    variance grows). A percentile bootstrap of the components was tried and rejected: its draws
    (units drawn twice, track noise counted twice) shifted the power down, and on planted crossed
    populations (20 objects x 8 scans) its interval missed the planted power in 5 of 10."""
    if not (df > 0 and v_now > 0):
        return {"ci_low": math.nan, "ci_high": math.nan, "df": df, "over": "the design's degrees of freedom"}
    hi_v = v_now * df / chi2.ppf((1 - level) / 2, df)
    lo_v = v_now * df / chi2.ppf((1 + level) / 2, df)
    return {"ci_low": power_at(math.sqrt(hi_v), effect), "ci_high": power_at(math.sqrt(lo_v), effect), "df": df,
            "over": "the variance's chi-square with the design's degrees of freedom"}


def _df(primary: Mapping, comp: Mapping) -> float:
    """The declared record's degrees of freedom (its design interval's), else the fewer units - 1."""
    rec = primary.get("record") or {}
    if rec.get("df") and math.isfinite(float(rec["df"])):
        return float(rec["df"])
    units = [g for g in (comp["n_objects"], comp["n_scans"]) if g > 1]
    return float(min(units) - 1) if units else math.nan


def power_block(d: pd.DataFrame, primary: Mapping, *, available: Mapping[str, int] | None = None,
                tracks_per_target: int | None = None, effect: float = EFFECT) -> dict:
    """summary.json's ``population.power`` for the declared primary comparison (``primary``: the
    ``population.primary`` block): the variance components, the power now for ``effect``, the
    objects, scans and tracks per cell 80 % power needs (each alone, the rest as run) and the
    config change that reaches it, or why the data cannot."""
    out = {"effect": effect, "power_goal": POWER, "alpha": ALPHA, "comparison": primary.get("comparison"),
           "metric": primary.get("metric"), "setting": primary.get("setting"),
           "adjustment": "none: the declared primary comparison is tested alone at two-sided 0.05"}
    if len(d) < 3:
        return {**out, "reading": "not estimable", "why": "fewer than 3 paired differences"}
    comp = components(d)
    out["components"] = comp
    if comp["object"] is None:
        return {**out, "reading": "not estimable", "why": "too few objects and scans to separate any term"}
    I, J, C, n = comp["n_objects"], comp["n_scans"], comp["n_cells"], comp["tracks_per_cell"]
    v_now, v_need = variance(comp, I, J, C, n), needed_variance(effect)
    out.update(se_now=math.sqrt(v_now), se_needed=math.sqrt(v_need), power_now=power_at(math.sqrt(v_now), effect))
    out["power_ci"] = power_interval(v_now, _df(primary, comp), effect)
    n_need = _tracks_for(comp, I, J, C, v_need)
    # more objects: each brings its C/I cells; more scans: each its C/J cells
    per_obj = {**comp, "interaction_per_unit": comp["interaction"] * I / C,
               "track_per_unit": (comp["track"] or 0.0) * I / (C * n)}
    per_scan = {**comp, "interaction_per_unit": comp["interaction"] * J / C,
                "track_per_unit": (comp["track"] or 0.0) * J / (C * n)}
    out["needed"] = {"tracks_per_cell": None if n_need is None else int(math.ceil(n_need - 1e-9)),
                     "objects": _units_for(per_obj, "object", comp["scan"] / J, v_need),
                     "scans": _units_for(per_scan, "scan", comp["object"] / I, v_need)}
    avail = {k: int(v) for k, v in (available or {}).items() if v}
    out["available"] = avail
    if out["power_now"] >= POWER:
        out["reading"] = "reached"
    elif n_need is not None and n_need * C / I <= MAX_TRACKS:
        per_target = int(math.ceil(n_need * C / I - 1e-9))
        out.update(reading="reachable by the config",
                   change={"evaluate.tracks_per_target": per_target, "now": tracks_per_target})
    else:
        Ia, Ja = max(I, avail.get("objects", I)), max(J, avail.get("scans", J))
        floor = variance(comp, Ia, Ja, C * (Ia / I) * (Ja / J), math.inf)
        out["floor_se"] = math.sqrt(floor)
        out["reading"] = ("not reachable with this data" if floor >= v_need else
                          "reachable only with more objects or scans than this run evaluates")
    return out
