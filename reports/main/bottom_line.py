"""The report's first lines, computed from ``summary.json``'s population (never hand-written): the
bottom line (what holds, what does not, over what it varies) and honest counts of the population.

Generic over the comparisons and metrics the verdict table holds: a new method or metric shows up
here without an edit (labels from ``pipeline.evaluation.metrics.labels``).
"""
from __future__ import annotations

import math
from collections import Counter

from pipeline.evaluation.metrics.spec import higher_is_better as _higher, metric_label
from pipeline.evaluation.statistics.multiplicity import adjusted
from reports.shared.records import join_words, outcome_clauses, records_of, sentence, too_few, varies_text


def counts(pop: dict) -> dict:
    """Targets, tracks per target (min–max), settings, cells and realizations per setting."""
    per_target = Counter(str(t.get("target")) for t in pop.get("tracks") or [] if isinstance(t, dict))
    targets = list(pop.get("targets") or per_target)
    n = [per_target[t] for t in targets if t in per_target]
    settings = pop.get("settings") or []
    reps = {str(s.get("setting")): s.get("realizations") or pop.get("realizations") for s in settings}
    kinds = {str(s.get("setting")): str(s.get("experiment") or "") for s in settings}
    return {"n_targets": int(pop.get("n_targets") or len(targets)), "n_tracks": int(pop.get("n_tracks") or sum(n)),
            "tracks_min": min(n) if n else None, "tracks_max": max(n) if n else None,
            "tracks_per_target": dict(per_target),
            "single_track_targets": sorted(t for t in targets if per_target.get(t) == 1),
            "n_settings": len(settings), "n_cells": pop.get("n_cells"), "realizations": reps,
            "single_realization_settings": [s for s, r in reps.items() if r == 1], "experiments": kinds}


def tracks_text(c: dict) -> str:
    lo, hi = c["tracks_min"], c["tracks_max"]
    per = "" if lo is None else (f", {lo} per target" if lo == hi else f", {lo}–{hi} per target")
    return f"{c['n_tracks']} tracks{per}"


def scope_text(c: dict) -> str:
    """'12 targets, 83 tracks (1–8 per target), 4 settings: 332 (target, track, setting) cells'."""
    reps = sorted({int(r) for r in c["realizations"].values() if r})
    r = "" if not reps else (f"; {reps[0]} realizations per cell" if len(reps) == 1 else
                             "; realizations per cell: " + realizations_text(c))
    cells = f": {c['n_cells']} (target, track, setting) cells" if c.get("n_cells") else ""
    return f"{c['n_targets']} targets, {tracks_text(c)}, {c['n_settings']} localization settings{cells}{r}"


def realizations_text(c: dict) -> str:
    """'1 (the biased setting), 30 (each of the 3 randomized settings)': grouped by experiment."""
    groups: dict[tuple[str, int], list[str]] = {}
    for s, r in c["realizations"].items():
        groups.setdefault((c.get("experiments", {}).get(s) or s, int(r or 0)), []).append(s)
    parts = []
    for (exp, r), names in groups.items():
        if exp in names:  # no experiment name: the setting itself
            parts.append(f"{r} ({exp})")
        else:
            parts.append(f"{r} ({'the ' + exp + ' setting' if len(names) == 1 else f'each of the {len(names)} {exp} settings'})")
    return ", ".join(parts)


SETTING_WORDS = {"all": "pooled over every localization setting of the run",
                 "biased": "in the biased setting", "randomized": "in the randomized setting",
                 "biased_randomized": "in the biased-plus-randomized setting, the paper's §5.5"}


def primary_line(pop: dict) -> str:
    """The declared primary comparison (``population.primary``, from ``evaluate.primary``) first:
    its verdict read off its own 95 % CI, not adjusted (the one comparison declared before the run)."""
    p = pop.get("primary") or {}
    if not p:
        return ""
    where = SETTING_WORDS.get(str(p.get("setting")), f"in the {p.get('setting')} setting")
    rec = p.get("record")
    if not rec:
        return (f"Primary comparison (declared before the run in evaluate.primary): {p.get('comparison')} on "
                f"{metric_label(str(p.get('metric')))} {where}: not measured ({p.get('missing', 'no cells')}).")
    # the record sits outside the primary_metrics family (no Holm): not "exploratory" here, it is the primary
    how = ("It has no verdict: its CI is withheld (the sentence says why)." if rec.get("withheld")
           else "Its verdict is read off its own 95 % CI, not adjusted: it is the one comparison declared.")
    return (f"Primary comparison (declared before the run in evaluate.primary, {where}): "
            f"{sentence({**rec, 'primary': None})} {how}")


def bottom_line(pop: dict, card: dict | None = None) -> list[str]:
    """The declared primary comparison's sentence first (``primary_line``), then the exploratory
    verdicts of the primary metrics (``evaluate.primary_metrics``, Holm-adjusted among themselves,
    separately from the primary comparison) per comparison, then what the CIs vary over."""
    recs = records_of(pop)
    table = [r for r in recs if r.get("primary")] or recs
    if not table:
        return []
    # the family's verdicts as Holm-adjusted (familywise 95 %); unadjusted where a record has none
    clauses = outcome_clauses([{**r, "outcome": adjusted(r)} for r in table])
    fam = next((r.get("family") for r in table if r.get("family")), None)
    c = counts(pop)
    prim = sorted({metric_label(r["metric"]) for r in table if r.get("primary")})
    lead = primary_line(pop)
    if lead:   # a declared primary comparison: the primary_metrics family is exploratory, Holm-adjusted on its own
        holm = (f"; Holm-adjusted among the {fam} comparisons of that family, familywise 95 %, separately from the "
                "primary comparison" if fam else "")
        first = ("Exploratory, as is everything else on this page, per-category and subgroup results included"
                 + (f" (the metrics of evaluate.primary_metrics: {join_words(prim)}{holm})" if prim else "") + ". "
                 + " ".join(cl + "." for cl in clauses))
    else:      # a run from before evaluate.primary
        holm = (f"; Holm-adjusted over the {fam} primary comparisons, familywise 95 %" if fam else "")
        first = ("Bottom line" + (f" (primary metrics: {join_words(prim)}; every other metric is exploratory{holm})"
                                  if prim else "") + ". " + " ".join(cl + "." for cl in clauses))
    seeds = "one classifier training run" if (card or {}).get("weights") == "synthetic" else "one classifier"
    r0 = table[0]
    group = {"scan": "scans", "category": "categories", "crossed": "scans"}.get(str(r0.get("cluster")))
    if group is None and "scans" in (r0.get("over") or []):   # a summary from before the cluster field
        group = "scans"
    n_top = (r0.get("n") or {}).get(group) if group else None
    scans = (f"{n_top} {group}" + (" crossed with " if r0.get("cluster") == "crossed" else ", ")) if n_top else ""
    levels = varies_text(r0) if r0.get("cluster") or not n_top else "scans, targets and tracks"
    held = [r for r in table if r.get("withheld")]   # no CI, no verdict: never counted among the outcomes
    head = ("Each outcome is read off the 95 % CI of a paired difference" if not held else
            f"No difference here has a CI or a verdict ({too_few(held)}): each is the point value of a paired "
            "difference" if len(held) == len(table) else
            f"{len(held)} of these {len(table)} differences carr{'ies' if len(held) == 1 else 'y'} no CI and no verdict "
            f"({too_few(held)}); each other "
            "outcome is read off the 95 % CI of a paired difference")
    second = (f"{head} over {scans}{c['n_targets']} targets and "
              f"{tracks_text(c)}{'' if len(held) == len(table) else f'; it varies over {levels} only'}, with {seeds} "
              "(the seed study, viewfuse study, repeats "
              "it over training seeds).")
    return [x for x in (lead, first, second) if x]


def higher_is_better(metric: str) -> bool:
    return _higher(metric)


def no_ci_reason(entry: dict | None, n_tracks: int | None) -> str:
    """Why an estimate has no CI ('' when it has one)."""
    e = entry or {}
    lo, hi = e.get("ci_low"), e.get("ci_high")
    ok = lo is not None and hi is not None and not (isinstance(lo, float) and math.isnan(lo)) \
        and not (isinstance(hi, float) and math.isnan(hi))
    if ok:
        return ""
    if n_tracks == 1:
        return "1 track: no CI (a CI over tracks needs at least 2)"
    return "no CI in summary.json"
