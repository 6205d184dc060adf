"""Tracks chosen by question: where With Uncertainty gains most over Model Based, where it loses
most, and a typical track, read off the population's per-cell values in summary.json (each
track's value is the mean over its settings, as in the pooled values). The detailed figures
further down show the one track the evaluate stage recorded (its rule is stated there); this
table says where that track sits and which tracks answer the other questions."""
from __future__ import annotations

from collections import defaultdict

import numpy as np

from pipeline.evaluation.metrics.labels import comparison_key, comparison_label
from pipeline.evaluation.metrics.spec import metric_label
from reports.main.context import ReportContext
from reports.shared.numbers import fmt

METHOD, BASELINE = "with_uncertainty", "model_based"
KEY_METRIC, TIE_METRIC = "correct_final", "prob_truth_final"


def track_differences(pop: dict, method: str = METHOD, baseline: str = BASELINE) -> list[tuple]:
    """(difference of KEY_METRIC, difference of TIE_METRIC, target, track), one per track: the mean
    over its settings of method − baseline, sorted by the key metric then the tie metric."""
    per: dict[tuple, list[tuple[float, float]]] = defaultdict(list)
    for c in pop.get("cells") or []:
        v = c.get("values") or {}
        a, b = v.get(method) or {}, v.get(baseline) or {}
        if KEY_METRIC in a and KEY_METRIC in b:
            per[(str(c.get("target")), int(c.get("track")))].append(
                (float(a[KEY_METRIC]) - float(b[KEY_METRIC]),
                 float(a.get(TIE_METRIC, np.nan)) - float(b.get(TIE_METRIC, np.nan))))
    rows = [(float(np.mean([d for d, _ in ds])), float(np.nanmean([t for _, t in ds])) if ds else np.nan, t, k)
            for (t, k), ds in per.items()]
    return sorted(rows, key=lambda r: (r[0], np.nan_to_num(r[1], nan=0.0), r[2], r[3]))


def by_question(pop: dict) -> list[tuple[str, tuple]]:
    """(question, track row) for the largest gain, the largest loss and the typical (median) track."""
    rows = track_differences(pop)
    if not rows:
        return []
    mid = float(np.median([r[0] for r in rows]))
    typical = min(rows, key=lambda r: (abs(r[0] - mid), r[2], r[3]))
    return [("largest gain", rows[-1]), ("largest loss", rows[0]), ("typical (median difference)", typical)]


def showcase_section(ctx: ReportContext) -> None:
    pop = ctx.population or {}
    picks = by_question(pop)
    if not picks:
        return
    ctx.section("Tracks chosen by question", "showcase")
    shown = pop.get("showcase") or {}
    here = (str(shown.get("target")), shown.get("track"))
    rows = [[q, f"{t}, track {k}" + (" (the track shown in detail below)" if (t, k) == here else ""),
             fmt(d, signed=True), fmt(p, signed=True)] for q, (d, p, t, k) in picks]
    n = len(track_differences(pop))
    gain, loss = picks[0][1][0], picks[1][1][0]
    ctx.page.table(["question", "track", f"Δ {metric_label(KEY_METRIC, short=True)}",
                    f"Δ {metric_label(TIE_METRIC, short=True)}"], rows, cls="showcase",
                   caption=f"{comparison_label(comparison_key(METHOD, BASELINE))} per track (mean over its settings), "
                           f"over {n} tracks: the differences run from {fmt(loss, signed=True)} to "
                           f"{fmt(gain, signed=True)}; ties are broken by the difference in P(truth). One track's "
                           "difference has no interval: it is one draw of the population, not an estimate.")
