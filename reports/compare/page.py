"""The comparison of ``reports.compare.runs`` as a terminal table and as an HTML page (the report's
own page style, numbers from ``reports.shared.numbers``)."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path
from typing import Any

from pipeline.evaluation.metrics.labels import comparison_label, method_label
from pipeline.evaluation.metrics.spec import metric_label
from pipeline.infra.outputs import path as out_path
from reports.compare.read import printable
from reports.compare.runs import Comparison
from reports.shared.html import HtmlReport
from reports.shared.numbers import Estimate, fmt
from reports.shared.records import outcome_text, pool_note


def _value(v: Any) -> str:
    if isinstance(v, float):
        return fmt(v)
    if isinstance(v, (list, dict)):
        return json.dumps(v, ensure_ascii=False)
    return str(v)


def _est(d: dict | None, signed: bool = False) -> str:
    return Estimate.of(d, signed=signed).text() if d else "—"


def _verdict_text(d: dict | None) -> str:
    if not d:
        return "—"
    holm = f"; Holm-adjusted outcome: {d['holm']}" if d.get("holm") else ""
    return f"{outcome_text(d)} ({Estimate.of(d, signed=True).text()}){holm}"


def headline(c: Comparison) -> str:
    n = len(c.runs)
    changed = sum(1 for row in c.changed.values() if any(row))
    keys = len(c.config)
    diff = (f"{keys} config key{'s differ' if keys != 1 else ' differs'}" if keys else "no config key differs")
    if len(c.columns) == 1:
        return f"1 run ({c.columns[0].name}): {len(c.verdicts)} verdict entries; nothing to compare against."
    return (f"{n} run{'s' if n != 1 else ''} in {len(c.columns)} columns; {diff}; {changed} of {len(c.verdicts)} "
            f"verdict entries change outcome against {c.columns[0].name}.")


# -- terminal ----------------------------------------------------------------------------------------
def _grid(header: list[str], rows: list[list[str]], marks: list[list[bool]] | None = None, width: int = 48) -> str:
    """Aligned columns; only the first (label) column is shortened to ``width``, values never."""
    # values come from run folders compare did not write: control characters are shown escaped
    cells = [[textwrap.shorten(printable(x), width=width, placeholder="…") if j == 0 else printable(x)
              for j, x in enumerate(r)] for r in [header] + rows]
    if marks:
        for i, row in enumerate(marks):
            for j, m in enumerate(row):
                if m:
                    cells[i + 1][j] = "*" + cells[i + 1][j]
    w = [max(len(r[j]) for r in cells) for j in range(len(header))]
    line = lambda r: "  ".join(x.ljust(w[j]) for j, x in enumerate(r)).rstrip()  # noqa: E731
    return "\n".join([line(cells[0]), "  ".join("-" * x for x in w)] + [line(r) for r in cells[1:]])


def render_text(c: Comparison) -> str:
    names = [col.name for col in c.columns]
    out = [printable(headline(c)), ""]
    if c.config:
        out += ["Config keys that differ:",
                _grid(["key"] + [r.name for r in c.runs], [[k] + [_value(v) for v in vals] for k, vals in c.config.items()]),
                ""]
    else:
        out += ["Config keys that differ: none" + (" (one run)" if len(c.runs) == 1 else ""), ""]
    rows = [[f"{metric_label(k, short=True)} · {method_label(m, short=True)}"] + [_est(v) for v in c.pooled[(m, k)]]
            for k in c.metrics for m in c.methods]
    out += ["Pooled values [95 % CI]:", _grid(["metric · method"] + names, rows), ""]
    vrows = [[f"{comparison_label(k[0])}: {metric_label(k[1], short=True)}"] + [_verdict_text(v) for v in row]
             for k, row in c.verdicts.items()]
    marks = [[False] + c.changed[k] for k in c.verdicts]
    out += ["Paired verdicts (* = outcome or Holm-adjusted outcome differs from the first column):",
            _grid(["comparison: metric"] + names, vrows, marks, width=56)]
    if c.planning:
        out += ["", "View planning, pooled [95 % CI]:",
                _grid(["metric · planner"] + names, [[f"{m} · {p}"] + [_est(v) for v in vals] for p, m, vals in c.planning]),
                "", "View-planning verdicts:",
                _grid(["comparison: metric"] + names, [[f"{k}: {m}"] + [_verdict_text(v) for v in vals]
                                                       for k, m, vals in c.planning_paired], width=56)]
    out += [f"note: {printable(n)}" for n in c.notes]
    return "\n".join(out) + "\n"


# -- HTML ----------------------------------------------------------------------------------------------
def build_page(c: Comparison, title: str = "viewfuse compare", intro: list[str] | None = None) -> HtmlReport:
    page = HtmlReport(title, subtitle=" · ".join(col.name for col in c.columns))
    names = [col.name for col in c.columns]
    page.section("Summary", anchor="summary")
    page.paragraph(headline(c), cls="bottomline")
    for p in intro or []:
        page.paragraph(p, cls="context")
    page.table(["run", "folder"], [[r.name, str(r.path)] for r in c.runs], cls="runs",
               caption="Runs compared (each read from its evaluate/summary.json and stage manifests only).")
    for n in c.notes:
        page.paragraph(n, cls="warn")
    page.section("Config keys that differ", anchor="config")
    if c.config:
        page.table(["key"] + [r.name for r in c.runs], [[k] + [_value(v) for v in vals] for k, vals in c.config.items()],
                   cls="config-diff", caption="Only the keys whose values differ between the runs (from the config "
                                              "sections each stage's manifest recorded); '—': the run has no such key.")
    else:
        page.paragraph("No config key differs between the runs." if len(c.runs) > 1 else "One run: nothing to diff.")
    page.section("Pooled values", anchor="pooled")
    pooled_cols = [col for col in c.columns if col.pooled_over_seeds]
    notes = [n.rstrip(".") for n in dict.fromkeys(pool_note(col.pool) for col in pooled_cols) if n]
    how = (" Seed-group columns pool the seeds' cells in one bootstrap over seeds, then targets, then tracks (the "
           "statistics engine, as `viewfuse study`): " + ("; ".join(notes) if notes else
                                                          "the CI covers classifier training runs") +
           "; each metric pooled over targets as in the main report." if pooled_cols else "")
    page.table(["metric", "method"] + names,
               [[metric_label(k), method_label(m, short=True)] + [Estimate.of(v) if v else None for v in c.pooled[(m, k)]]
                for k in c.metrics for m in c.methods], cls="pooled-compare",
               caption="Each run's pooled value [95 % CI over targets and tracks]." + how)
    page.section("Paired verdicts", anchor="verdicts")
    rows, marks = [], set()
    for i, (k, row) in enumerate(c.verdicts.items()):
        rows.append([comparison_label(k[0]), metric_label(k[1])] + [_verdict_text(v) for v in row])
        marks |= {(i, j + 2) for j, ch in enumerate(c.changed[k]) if ch}
    page.table(["comparison", "metric"] + names, rows, cls="verdict-compare", highlight=marks,
               caption="Outcome of each paired difference (better / worse / not distinguishable: its 95 % CI above, "
                       "below or across 0) with the difference [95 % CI]; for the primary comparisons (With "
                       "Uncertainty against each baseline on the primary metrics) also the Holm-adjusted outcome, "
                       "familywise 95 % as on the main report (each interval widened to its Holm step's level); "
                       "shaded: the outcome or the adjusted one differs from the first column. A seed group's "
                       "outcome is that of the difference pooled over its seeds.")
    if c.planning:
        page.section("View planning", anchor="planning")
        page.table(["metric", "planner"] + names,
                   [[m, p] + [Estimate.of(v) if v else None for v in vals] for p, m, vals in c.planning],
                   cls="planning-compare", caption="Each run's pooled planning metric [95 % CI over targets and "
                                                   "starts] (evaluate/summary.json, planning block).")
        page.table(["comparison", "metric"] + names,
                   [[k, m] + [_verdict_text(v) for v in vals] for k, m, vals in c.planning_paired],
                   cls="planning-verdicts", caption="Paired planning verdicts (the difference's 95 % CI above, below "
                                                    "or across 0).")
    return page


def write_page(c: Comparison, out_dir: str | Path, title: str = "viewfuse compare",
               intro: list[str] | None = None) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out_path(out, "compare", "html")
    build_page(c, title, intro).write(path)
    return path

