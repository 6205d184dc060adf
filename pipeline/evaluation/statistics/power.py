"""Power, stated: how wide each primary comparison's interval is, and what population would make it
narrow enough to decide.

The interval of a pooled value comes from resampling the hierarchy's top level (scans, or targets
when there is no scan level) and the levels under it. With the composition of each top-level unit
kept (the same targets per scan, tracks per target, settings and realizations), the variance of the
resampled statistic falls as 1 / n, n the number of top-level units, so its half-width falls as
1 / sqrt(n). The population that brings an observed half-width ``w`` at ``n`` units to ``goal`` is
then ``ceil(n (w / goal)^2)`` units: a projection from the observed between-unit variance, not a
guarantee (the next units may vary more or less than these did). The cost of that population is
the measured cost scaled by the same factor, as every stage's work grows linearly with the units.

A crossed design (``cluster = "crossed"``: targets and scans resampled independently) has two top
levels: the variance is a target term over n_targets plus a scan term over n_scans, so more targets
alone leave the scan term as it is. The projection scales both by the same factor k (the variance
then falls as 1 / k, as above) and names both counts (``needed_units`` targets, ``needed_scans``).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

MIN_UNITS = 5  # fewer top-level units than this: the bootstrap's spread is too coarse to project from
GOAL = 0.05   # the half-width a primary comparison's interval should reach to decide a 0.05 difference

ASSUMPTION = ("half-width proportional to 1/sqrt(n) over the top level's units (each unit's composition kept: "
              "targets per scan, tracks per target, settings and realizations); projected from the observed "
              "between-unit variance; cost = the measured seconds scaled by the same factor; a crossed design "
              "(targets x scans) scales targets and scans together")


def half_width(lo: float | None, hi: float | None) -> float:
    """Half the interval's width: NaN where there is no interval, inf where an end is unbounded
    (None, as JSON writes it)."""
    if lo is None or hi is None:
        return math.inf
    lo, hi = float(lo), float(hi)
    return (hi - lo) / 2 if not (math.isnan(lo) or math.isnan(hi)) else math.nan


def needed_units(width: float, n_units: int, goal: float = GOAL) -> int | None:
    """The top-level units that bring a half-width ``width`` observed at ``n_units`` to ``goal``
    (``n_units`` itself when it is already there); None when the width is undefined or unbounded."""
    if not math.isfinite(width) or n_units < 1:
        return None
    if width <= goal:
        return int(n_units)
    return int(math.ceil(n_units * (width / goal) ** 2 - 1e-9))


def power_block(records: Sequence[Mapping], seconds: float | None = None, goal: float = GOAL,
                available: Mapping[str, int] | None = None) -> dict:
    """For each primary record (``records.record``): its half-width, the top-level unit and its
    count, the units (and targets) that would bring the half-width to ``goal`` and what that costs
    (``seconds``, the measured seconds of this population, times the scale). ``available``: the
    most units of a level that exist (e.g. {"scans": 15}): a projection past it says so."""
    out = []
    for r in records:
        if not r.get("primary"):
            continue
        over, n = list(r.get("over") or []), dict(r.get("n") or {})
        top = next((u for u in over if u != "seeds" and n.get(u)), "targets")
        n_top = int(n.get(top, 0))
        w = half_width(r.get("lo"), r.get("hi"))
        need = needed_units(w, n_top, goal)
        scale = None if need is None or n_top < 1 else need / n_top
        entry = {"comparison": r["comparison"], "metric": r["metric"], "half_width": w, "goal": goal,
                 "reached": bool(math.isfinite(w) and w <= goal), "unit": top, "n_units": n_top,
                 "needed_units": need, "scale": scale,
                 "needed_targets": None if scale is None else int(math.ceil(scale * int(n.get("targets", 0)))),
                 "needed_tracks": None if scale is None else int(math.ceil(scale * int(n.get("tracks", 0)))),
                 "cost_s": None if scale is None or seconds is None else float(seconds) * scale}
        few = (n_top, top)   # the top level with the fewest units
        if r.get("cluster") == "crossed" and n.get("scans"):   # both top levels grow together
            n_scans = int(n["scans"])
            entry.update(crossed_with="scans", n_scans=n_scans,
                         needed_scans=None if scale is None else int(math.ceil(scale * n_scans - 1e-9)))
            few = min(few, (n_scans, "scans"))
        if few[0] < MIN_UNITS:
            entry["caution"] = (f"{few[0]} {few[1]}: a bootstrap over so few units understates their spread; the "
                                "projection is a lower bound")
        if available and top in available and need is not None and need > available[top]:
            entry["beyond"] = f"{need} {top} needed, {available[top]} exist"
        more = entry.get("needed_scans")
        if available and entry.get("crossed_with") and "scans" in available and more and more > available["scans"]:
            entry["beyond"] = f"{more} scans needed, {available['scans']} exist"
        out.append(entry)
    return {"goal": goal, "assumption": ASSUMPTION, "seconds_measured": seconds, "comparisons": out}
