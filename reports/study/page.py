"""The seed study's page (``viewfuse study``): the verdict per seed side by side, pooled values
with their CIs, every seed's verdict sentences. Numbers go through ``reports.shared.numbers.fmt``, as in
the main report; the stage (``stages.commands.study``) gathers the summary this renders."""
from __future__ import annotations

import html
from typing import Any

from pipeline.evaluation.metrics.labels import method_label, ordered_methods
from pipeline.evaluation.metrics.spec import metric_label
from reports.shared.html import format_cell
from reports.shared.records import holm_text, outcome_clauses, pool_note, records_of, sentences


def entry_label(key: str) -> str:
    """'with_uncertainty-model_based / correct_final' -> 'With Uncertainty vs Model Based, correct
    ratio, final step' (keys that are not (comparison / metric) are shown as they are)."""
    comp, _, metric = key.partition(" / ")
    a, _, b = comp.partition("-")
    if not metric or not b:
        return key
    return f"{method_label(a, short=True)} vs {method_label(b, short=True)}, {metric_label(metric)}"


def study_sentence(seeds: list, missing: list, differ: list[str], n_entries: int, held: dict[str, str]) -> str:
    """The study's answer: whether every seed reaches the same verdict, and the decided outcomes
    held for every seed (``held``: (comparison / metric) -> outcome), worded by the records'
    renderer (``reports.shared.records.outcome_clauses``)."""
    if missing:
        return (f"Seed(s) {', '.join(map(str, missing))} have no population verdict (evaluate/summary.json "
                f"lacks 'population'); the verdicts cannot be compared yet.")
    n_held = sum(o == "withheld" for o in held.values())   # no CI, no verdict: never counted among the verdicts
    if not differ and n_entries and n_held == n_entries:
        return (f"No seed ({', '.join(map(str, seeds))}) reaches a verdict to compare: every entry's CI is withheld "
                "(too few units of a level the design varies over).")
    if not differ:
        text = f"The verdict is the same for every seed ({', '.join(map(str, seeds))})."
    else:
        text = (f"The verdict differs between seeds on {len(differ)} of {n_entries} "
                f"(comparison / metric) entries: {'; '.join(entry_label(k) for k in differ)}.")
    decided = [{"comparison": k.partition(" / ")[0], "metric": k.partition(" / ")[2], "outcome": o}
               for k, o in held.items() if o in ("better", "worse")]
    if decided:
        text += " Held for every seed: " + "; ".join(outcome_clauses(decided)) + "."
    if n_held:   # said apart, with why
        text += (f" {n_held} of {n_entries} entries carr{'ies' if n_held == 1 else 'y'} no CI and no verdict in every "
                 "seed (too few units of a "
                 "level the design varies over).")
    return text


def _text(v: Any) -> str:
    return html.escape(format_cell(v)[0])


def _cell(entry: Any) -> str:
    if not isinstance(entry, dict):
        return _text(entry)
    return f"{_text(entry.get('value'))} <small>[{_text(entry.get('ci_low'))}, {_text(entry.get('ci_high'))}]</small>"


def _accuracy(seed: dict) -> str:
    """Held-out top-1 with its 95 % CI over the held-out images, where the card has one."""
    ci = seed.get("classifier_accuracy_ci95")
    if not ci:
        return _text(seed.get("classifier_accuracy"))
    return _cell({"value": seed.get("classifier_accuracy"), "ci_low": ci[0], "ci_high": ci[1]})


def adjusted_outcomes(block: dict | None) -> dict[str, str]:
    """(comparison / metric) -> the Holm-adjusted verdict of a primary-family record
    (``reports.shared.records.holm_text``, as the main report words it); others are absent."""
    return {f"{r['comparison']} / {r['metric']}": holm_text(r) for r in records_of(block) if r.get("outcome_holm")}


def _outcome_cell(outcome: Any, holm: str | None) -> str:
    """A seed's verdict, and beside it its Holm-adjusted one where the record is in the primary family."""
    if not holm:
        return _text(outcome)
    return f"{_text(outcome)}<br><small>Holm-adjusted outcome: {html.escape(holm)}</small>"


def holm_table(block: dict | None) -> str:
    """The pooled-over-seeds primary family: outcome and Holm-adjusted outcome side by side."""
    recs = [r for r in records_of(block) if r.get("outcome_holm")]
    if not recs:
        return ""
    fam = recs[0].get("family")
    rows = "".join(f"<tr><td>{html.escape(entry_label(r['comparison'] + ' / ' + r['metric']))}</td>"
                   f"<td>{_text(r['outcome'])}</td><td>{html.escape(holm_text(r))}</td></tr>" for r in recs)
    return (f"<table><tr><th>comparison, metric</th><th>outcome</th><th>Holm-adjusted outcome</th></tr>{rows}"
            f"</table><p><small>Holm-adjusted: the {fam} primary comparisons (With Uncertainty against each baseline "
            "on the primary metrics) as one family, familywise 95 % (each interval widened to its Holm step's "
            "level), as on the main report.</small></p>")


def render_html(summary: dict, run_name: str) -> str:
    """One page: the answer (does the verdict hold across seeds), the outcome per entry and seed,
    then the pooled values with their CIs and every seed's verdict sentences."""
    seeds = [str(s) for s in summary["seeds"]]
    per = summary["per_seed"]
    head = "".join(f"<th>seed {s}</th>" for s in seeds)
    out_rows = []
    adjusted = {s: adjusted_outcomes(per[s]) for s in seeds}
    for k, row in summary["outcomes"].items():
        cls = ' class="differs"' if k in summary["differs_on"] else ""
        out_rows.append(f"<tr{cls}><td>{html.escape(entry_label(k))}</td>"
                        + "".join(f"<td>{_outcome_cell(row[s], adjusted[s].get(k))}</td>" for s in seeds) + "</tr>")
    rows = [f"<tr><td>classifier held-out top-1 <small>[95 % CI over the held-out images]</small></td>"
            + "".join(f"<td>{_accuracy(per[s])}</td>" for s in seeds) + "</tr>",
            "<tr><td>GP fits with varying scores (std over views &gt; 0.01) · at a bound</td>"
            + "".join(f"<td>{_text(per[s].get('varying_fits'))} · {_text(per[s].get('varying_fits_at_bound'))}</td>"
                      for s in seeds) + "</tr>"]
    chain = (summary.get("timings_s") or {}).get("chain_per_seed") or {}
    if chain:
        rows.append("<tr><td>seconds to compute the chain (classifier + features + models + evaluate)</td>"
                    + "".join(f"<td>{_text(sum(v for v in (chain.get(s) or {}).values() if v is not None) or None)}</td>"
                              for s in seeds) + "</tr>")
    pooled = [per[s].get("pooled") or {} for s in seeds]
    methods = ordered_methods({m for p in pooled for m in p})
    metrics = list(dict.fromkeys(k for p in pooled for d in p.values() for k in d))
    for k in metrics:
        for m in methods:
            rows.append(f"<tr><td>{html.escape(metric_label(k))} · {html.escape(method_label(m, short=True))}</td>"
                        + "".join(f"<td>{_cell((p.get(m) or {}).get(k))}</td>" for p in pooled) + "</tr>")
    sp = summary.get("pooled_over_seeds") or {}
    note = pool_note(sp)
    seed_verdict = ("<h2>Pooled over seeds</h2><p>" + (html.escape(note) if note else "One bootstrap over seeds, then "
                    "targets, then tracks: these CIs cover classifier training runs.") + "</p><ul>"
                    + "".join(f"<li>{html.escape(v)}</li>" for v in sentences(records_of(sp))) + "</ul>"
                    + holm_table(sp)) if sp else ""
    verdicts = "".join(f"<h3>seed {s}{' (reused)' if per[s].get('reused') else ''}</h3><ul>"
                       + "".join(f"<li>{html.escape(v)}</li>" for v in (sentences(records_of(per[s])) or ["(no verdict)"]))
                       + "</ul>" for s in seeds)
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>viewfuse seed study: {html.escape(run_name)}</title>
<style>body{{font-family:sans-serif;max-width:75em;margin:1em auto;line-height:1.4}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:.2em .5em;text-align:right}}td:first-child,th:first-child{{text-align:left}}
tr.differs td{{background:#fde2e2}}small{{color:#666}}</style></head><body>
<h1>Seed study: {html.escape(run_name)}</h1>
<p><b>{html.escape(summary['sentence'])}</b></p>
<p>Each seed trains the classifier again (classifier.seed) and reruns features, models and evaluate on the
same data. An outcome is computed from the 95 % bootstrap CI of the paired difference over targets and tracks
(better / worse: the CI excludes 0); rows where the seeds disagree are shaded. The primary comparisons also
show their Holm-adjusted outcome (familywise 95 % over the primary family, as on the main report).</p>
{seed_verdict}
<h2>Verdict per seed</h2><table><tr><th>comparison, metric</th>{head}</tr>{''.join(out_rows)}</table>
<h2>Pooled values</h2>
<p>Value with its 95 % bootstrap CI over targets, then tracks within targets; MGR as log10.</p>
<table><tr><th>metric · method</th>{head}</tr>{''.join(rows)}</table>
<h2>Verdict sentences</h2>{verdicts}
</body></html>
"""
