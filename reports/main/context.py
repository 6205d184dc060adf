"""What every section of the main report reads: the run's artifacts and what was derived once."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from reports.shared.artifacts import RunArtifacts
from reports.shared.checks import Ledger, caption_problem
from reports.shared.html import HtmlReport
from pipeline.infra.datasets import described


# sections that report no result besides the declared primary comparison
NOT_EXPLORATORY = frozenset({"verdict", "power", "methods", "limitations", "glossary", "reproduce", "details"})


@dataclass
class ReportContext:
    page: HtmlReport
    run: RunArtifacts
    run_name: str = ""
    config: dict = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    figures: set[str] = field(default_factory=set)          # PNGs written
    notes: list[str] = field(default_factory=list)          # warnings shown on the page and logged
    sections: list[str] = field(default_factory=list)       # anchors, in page order
    track_summaries: dict[str, dict] = field(default_factory=dict)  # experiment -> stats.track_summary
    comp_names: list[str] = field(default_factory=list)
    clipped: dict[str, int] = field(default_factory=dict)   # figure -> +inf values drawn at the axis top
    n_boot: int = 0
    checks: dict[str, Any] = field(default_factory=dict)    # figure -> reports.shared.figures.FigureCheck
    alts: dict[str, str] = field(default_factory=dict)      # figure -> alt text stating its finding
    bias_findings: dict | None = None                       # reports.main.figures_models.bias_map_findings
    ledger: Ledger = field(default_factory=Ledger)          # every printed statistic (reports/shared/checks.py)
    problems: list[str] = field(default_factory=list)       # contradictions and captions: always fatal
    layout_problems: dict[str, list[str]] = field(default_factory=dict)  # figure -> text slips after layout
    commit: str = ""                                        # the code's git commit (the report stage passes it)
    config_file: str = ""                                   # the --config file of the run       # self-check failures: the build stops on any

    @property
    def ev(self):
        return self.run.evaluate

    @property
    def population(self) -> dict | None:
        return self.run.evaluate.population

    @property
    def data_source(self) -> str:
        """'synthetic' or 'real' (from the resolved config, else the data stage's manifest)."""
        src = (self.config.get("data") or {}).get("source")
        if not src:
            parts = (self.run.manifests.get("data") or {}).get("parts") or {}
            src = _find(parts, "source")
        return str(src or "unknown")

    @property
    def source(self):
        """The registered ``DatasetSource`` of ``data_source``: what the page says of the data (its
        ``describe``, ``badge``, ``rendered``) is the source's own, so one from outside gets its wording."""

        return described(self.data_source)

    def section(self, title: str, anchor: str) -> None:
        # with a declared primary comparison (evaluate.primary) every result section but the verdict
        # (which reads the primary first) and the power statement (about the primary) is exploratory
        if anchor not in NOT_EXPLORATORY and (self.population or {}).get("primary"):
            title += " (exploratory)"
        self.page.section(title, anchor=anchor)
        self.sections.append(anchor)

    def figure(self, name: str, caption: str) -> None:
        """A figure only where it was drawn (a missing one would be a broken image), with the alt
        text of its finding and its smallest text size."""
        if name in self.figures:
            chk = self.checks.get(name)
            alt = self.alts.get(name, "")
            # The caption says what the figure shows, then what it finds (the alt text's finding).
            caption = f"{caption} {alt}".strip() if alt and alt not in caption else caption
            problem = caption_problem(name, caption)
            if problem:
                self.problems.append(problem)
            self.page.figure(name, caption, alt=alt,
                             min_font_px=getattr(chk, "min_font_px", None),
                             tick_overlaps=len(chk.overlaps) if chk is not None else None,
                             warning=_layout_warning(self.layout_problems.get(name)))


def _layout_warning(slips: list[str] | None) -> str:
    """The box a figure with a layout slip carries on the page ('' when it has none)."""
    if not slips:
        return ""
    what = "; ".join(s.split(": ", 1)[-1] for s in slips[:3]) + (f"; and {len(slips) - 3} more" if len(slips) > 3 else "")
    return (f"Layout check: some text of this figure overlaps or is cut off ({what}). The numbers are "
            "unaffected; the tables and the caption state them.")


def _find(d: Any, key: str) -> Any:
    if isinstance(d, dict):
        if key in d and not isinstance(d[key], dict):
            return d[key]
        for v in d.values():
            r = _find(v, key)
            if r is not None:
                return r
    return None
