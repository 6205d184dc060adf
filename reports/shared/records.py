"""The one renderer of verdict sentences: prose from the structured records of ``summary.json``
(``pipeline.evaluation.statistics.records``), never stored as text. Every page that states a
verdict (main report, calibration, ablations, study, compare) renders it here, so the label, the
number and its interval in a sentence are the record's own.

Forms: ``sentence`` (one record, in full), ``clause`` (one record in a few words: alt texts,
table cells) and ``outcome_clauses`` (several records, one clause per comparison naming only the
outcomes: the bottom line, the ablation table, the seed study)."""
from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from pipeline.evaluation.metrics.labels import method_label
from pipeline.evaluation.metrics.spec import metric_label
from reports.shared.numbers import fmt, percent, plain

PHRASE = {"better": "is better than", "worse": "is worse than", "not distinguishable": "is not distinguishable from",
          "withheld": "vs"}   # withheld: no verdict; the interval text says why (``interval_text``)
STATISTIC = {"mean": "mean over targets of the differences",
             "median": "median over targets of the target differences",
             "pooled posteriors": "difference of the pooled-posterior values"}
# What an interval varies over, per clustering (a record's ``cluster``: evaluate.statistics.cluster).
VARIES = {"target": "targets and tracks", "scan": "scans, targets and tracks",
          "category": "categories, targets and tracks", "crossed": "targets and scans, crossed"}
GROUP = {"scan": "scans", "category": "categories"}
SINGULAR = {"categories": "category", "seeds": "seed", "scans": "scan", "targets": "target", "tracks": "track",
            "starts": "start"}


def varies_text(rec: Mapping) -> str:
    """'categories, targets and tracks': the levels a record's (or a summary's) interval resamples."""
    c = rec.get("cluster")
    if c in ("target", "category") and "scans" in (rec.get("levels") or {}):   # the design interval counts the scans
        return join_words(list(rec.get("over") or []))
    if c in VARIES:
        return VARIES[c]
    return join_words(list(rec.get("over") or ["targets", "tracks"]))


def statistic_text(rec: Mapping) -> str:
    """The pooled statistic in words: over targets, or over the groups on top (scans, categories)
    of their targets' values."""
    pool, group = rec.get("pooling"), GROUP.get(str(rec.get("cluster")))
    if group and pool in ("mean", "median"):
        return f"{pool} over {group} of their targets' {pool} differences"
    return STATISTIC.get(pool, "difference")


def records_of(block: Mapping | None) -> list[dict]:
    """A block's records (``records``; an older summary's ``verdict_table`` rows, renamed)."""
    b = block or {}
    if b.get("records"):
        return list(b["records"])
    return [{**r, "lo": r.get("ci_low"), "hi": r.get("ci_high")} for r in b.get("verdict_table") or []]


def _end(x: Any, side: int) -> str:
    if x is None:  # JSON's infinity: the interval is unbounded on that side
        return ("+" if side > 0 else "−") + "∞"
    return fmt(x, signed=True)


def interval_text(rec: Mapping) -> str:
    """'95 % CI [lo, hi]'; 'no CI' without one, with the reason where the engine withheld it (too
    few clusters for a calibrated interval: no verdict follows)."""
    if rec.get("withheld"):
        return f"no CI, no verdict: {rec['withheld']}"
    lo, hi = rec.get("lo"), rec.get("hi")
    nan = lambda x: isinstance(x, float) and math.isnan(x)
    if (lo is None and hi is None and not rec.get("unbounded")) or nan(lo) or nan(hi):
        return "no CI"
    return f"95 % CI [{_end(lo, -1)}, {_end(hi, +1)}]"


def outcome_text(rec: Mapping) -> str:
    """The record's outcome as a table cell prints it: better / worse / not distinguishable, or
    'no CI, no verdict: <too few units>' where the engine withheld its interval."""
    if rec.get("withheld"):
        return f"no CI, no verdict: {str(rec['withheld']).split(':')[0]} (too few units)"
    return str(rec.get("outcome"))


def over_text(rec: Mapping) -> str:
    n, over = rec.get("n") or {}, list(rec.get("over") or [])
    word = lambda k: f"{n[k]} {k if n[k] != 1 else SINGULAR[k]}"
    if rec.get("cluster") == "crossed" and "targets" in n and "scans" in n:
        return f"{word('targets')} crossed with {word('scans')}"
    parts = [word(k) for k in ("seeds", "scans", "categories", "targets", "tracks", "starts")
             if k in n and (k in over or not over or k in ("targets", "tracks", "starts"))]
    return " × ".join(parts) if parts else " and ".join(over)


def sides(rec: Mapping, name: Callable[[str], str] | None = None) -> tuple[str, str]:
    """The record's method and baseline in words (``name``: another family's; by default the
    methods' short labels). An older summary's row has only ``comparison``: its two keys."""
    a, _, b = str(rec.get("comparison") or "").partition("-")
    a, b = rec.get("method", a), rec.get("baseline", b)
    word = name or (lambda k: method_label(k, short=True))
    return word(a), word(b)


def sentence(rec: Mapping, *, name: Callable[[str], str] | None = None,
             metric_name: Callable[[str], str] | None = None) -> str:
    """One record as a sentence: outcome, statistic, value, interval, what it varies over, the
    wins/losses and the caveats the record carries. ``name`` and ``metric_name`` word another
    family's entries (the view planners and their metrics); by default methods and metrics."""
    a, b = sides(rec, name)
    stat = statistic_text(rec)
    what = (metric_name or metric_label)(rec["metric"])
    text = (f"{a} {PHRASE[rec['outcome']]} {b} on {what} ({stat} "
            f"{fmt(rec.get('value'), signed=True)}, {interval_text(rec)}, over {over_text(rec)}")
    lmin, lmax = rec.get("loto_min"), rec.get("loto_max")
    if isinstance(lmin, (int, float)) and isinstance(lmax, (int, float)) and math.isfinite(lmin) and math.isfinite(lmax):
        text += f"; leaving one target out: {fmt(lmin, signed=True)} to {fmt(lmax, signed=True)}"
    unit = rec.get("unit") or "cells"
    if rec.get("wins") is not None and rec.get("losses") is not None:
        text += f"; better in {percent(rec['wins'])} of {unit}, worse in {percent(rec['losses'])}"
    text += ")"
    notes = []
    flips = [] if rec.get("withheld") else rec.get("loto_flips") or []   # withheld: no outcome to change
    if flips:
        more = f" (or another of {len(flips)})" if len(flips) > 3 else ""
        notes.append(f"leaving out {' or '.join(flips[:3])}{more} alone changes the outcome")
    if rec["outcome"] == "better" and (rec.get("losses") or 0) > (rec.get("wins") or 0):
        notes.append(f"it loses more {unit} than it wins")
    if rec["outcome"] == "worse" and (rec.get("wins") or 0) > (rec.get("losses") or 0):
        notes.append(f"it wins more {unit} than it loses")
    cells = (rec.get("n") or {}).get("cells")
    if rec.get("ceiling_cells"):
        notes.append(f"{rec['ceiling_cells']} of {cells} cells had both methods at the best possible value")
    if rec.get("floor_cells"):
        notes.append(f"{rec['floor_cells']} of {cells} at the worst")
    if rec.get("outcome_holm") and rec["outcome_holm"] != rec["outcome"]:
        notes.append(f"{rec['outcome_holm']} after the Holm adjustment over the {rec.get('family')} primary "
                     "comparisons")
    if rec.get("declared"):
        notes.append("the declared primary comparison (evaluate.primary): tested alone at 95 %, outside the Holm "
                     "family")
    if rec.get("primary") is False:
        notes.append("exploratory metric")
    return text + ("; " + "; ".join(notes) if notes else "") + "."


def clause(rec: Mapping, *, name: Callable[[str], str] | None = None,
           metric_name: Callable[[str], str] | None = None) -> str:
    """One record in a few words (an alt text's, a table cell's): '<method> − <baseline>,
    <metric>: <value>, 95 % CI [lo, hi] (<outcome>)', the value, interval and outcome of ``sentence``."""
    a, b = sides(rec, name)
    what = (metric_name or metric_label)(rec["metric"])
    tail = "" if rec.get("withheld") else f" ({rec['outcome']})"   # withheld: the interval text says no verdict
    return f"{a} − {b}, {what}: {fmt(rec.get('value'), signed=True)}, {interval_text(rec)}{tail}"


def holm_text(rec: Mapping) -> str:
    """A primary-family record's adjusted verdict with its widened interval: 'not distinguishable
    (98.3 % CI [−0.01, +0.05]; Holm p 0.06)'; '' outside the family."""
    if not rec.get("outcome_holm"):
        return ""
    level = 100 * float(rec.get("level_holm") or 0.95)
    ci = interval_text({"lo": rec.get("lo_holm"), "hi": rec.get("hi_holm"),
                        "unbounded": rec.get("lo_holm") is None or rec.get("hi_holm") is None})
    return (f"{rec['outcome_holm']} ({ci.replace('95 %', f'{plain(level)} %')}; Holm p {fmt(rec.get('p_holm'))})")


def metric_family(metric: str) -> str:
    """'log10 MGR 95th percentile, final step' -> 'log10 MGR'; 'correct ratio, final step' -> 'correct ratio'."""
    head = metric_label(metric).split(",")[0]
    return re.sub(r"\s*\d+(st|nd|rd|th) percentile", "", head).strip()


def join_words(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _grouped(outcomes: Mapping[str, str]) -> dict[str, list[str]]:
    """Outcome -> phrases: a metric family whose entries share one outcome is named once."""
    fam: dict[str, list[str]] = {}
    for m in outcomes:
        fam.setdefault(metric_family(m), []).append(m)
    out: dict[str, list[str]] = {o: [] for o in PHRASE}
    for family, ms in fam.items():
        kinds = {outcomes[m] for m in ms}
        if len(kinds) == 1:
            out.setdefault(kinds.pop(), []).append(family + (f" (all {len(ms)} entries)" if len(ms) > 2 else ""))
        else:
            for m in ms:
                out.setdefault(outcomes[m], []).append(metric_label(m))
    return out


def outcome_clauses(records: Iterable[Mapping], *, subject: bool = True,
                    name: Callable[[str], str] | None = None) -> list[str]:
    """Several records, outcomes only: one clause per comparison, in record order ('<method> vs
    <baseline>: better on correct ratio; not distinguishable on log10 MGR'; '<method> is not
    distinguishable from <baseline> on any metric'). A metric family whose entries share one
    outcome is named once. Without ``subject`` the clause starts at the outcomes (a table row
    that names its comparison elsewhere)."""
    by: dict[str, list[Mapping]] = {}
    for r in records:
        by.setdefault(str(r.get("comparison")), []).append(r)
    out = []
    for recs in by.values():
        a, b = sides(recs[0], name)
        g = _grouped({str(r["metric"]): str(r["outcome"]) for r in recs})
        if g["withheld"]:   # no CI, no verdict: said as such, never as "not distinguishable", with which level
            held = f"no verdict (no CI: {too_few(recs)}) on " + (
                "any metric" if len(g["withheld"]) == len(recs) else join_words(g["withheld"]))
            said = "; ".join([f"{o} on {join_words(g[o])}" for o in PHRASE if o != "withheld" and g.get(o)] + [held])
            out.append(f"{a} vs {b}: {said}" if subject else said)
            continue
        if not g["better"] and not g["worse"]:
            out.append(f"{a} is not distinguishable from {b} on any metric" if subject
                       else "not distinguishable on any metric")
            continue
        said = "; ".join(f"{o} on {join_words(g[o])}" for o in PHRASE if g.get(o))
        out.append(f"{a} vs {b}: {said}" if subject else said)
    return out


def too_few(records: Iterable[Mapping]) -> str:
    """'2 scans, too few units' from the withheld records' reasons (``design.withheld``: the level
    and its count before the colon); 'too few units' where a record does not carry its reason."""
    why = list(dict.fromkeys(str(r["withheld"]).split(":")[0] for r in records if r.get("withheld")))
    return ", ".join(why + ["too few units"])


def pool_note(block: Mapping | None) -> str:
    """Why a seed pool (``engine.seed_pool``) has no CI and no verdict, '' where it has them: its
    draws resample the seeds on top, then each seed's targets, so the rule for every interval
    (``design.withheld``) counts the seeds as a level."""
    held = [r for r in records_of(block) if r.get("withheld")]
    if not held:
        return ""
    return (f"Pooled over the seeds, these values carry no CI and no verdict ({too_few(held[:1])}): the bootstrap "
            "resamples the seeds on top, then each seed's targets, so the seeds are a level the interval varies over, "
            "and a calibrated interval needs at least 8 units of every level (docs/calibration.md).")


def find(records: Iterable[Mapping], comparison: str, metric: str) -> Mapping | None:
    """The record of (comparison, metric), or None."""
    return next((r for r in records if r.get("comparison") == comparison and r.get("metric") == metric), None)


def select(records: Iterable[Mapping], metrics: Sequence[str] | None = None, *, primary: bool | None = None) -> list:
    """The records of ``metrics`` (in record order; None: all), only primary ones with ``primary``."""
    out = [r for r in records if metrics is None or r.get("metric") in metrics]
    return [r for r in out if primary is None or bool(r.get("primary")) == primary]


def sentences(records: Iterable[Mapping], metrics: Sequence[str] | None = None) -> list[str]:
    return [sentence(r) for r in select(records, metrics)]
