"""The report's section on the model-uncertainty source: does a crop's MC spread rank how far its
scores fall from its class model? Read from ``summary.json`` (``population.domain_fit.
uncertainty_source``, computed by ``pipeline.evaluation.domain.source``); this module only words it."""
from __future__ import annotations

from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt


def source_rows(src: dict) -> list[list]:
    """Rows: statistic, value [95 % CI], what chance reads."""
    return [["Spearman ρ (spread, |z|)", Estimate.of(src.get("rho"), signed=True), "0"],
            [f"AUROC of the spread for {src.get('far', '|z| > 2')} (share of crops: {fmt(src.get('far_share'))})",
             Estimate.of(src.get("auroc")), "0.5"]]


def uncertainty_source_section(ctx: ReportContext) -> None:
    dom = (ctx.population or {}).get("domain_fit") or {}
    src = dom.get("uncertainty_source") or {}
    if not src:
        return
    ctx.section("Does the MC spread track the distance from the class model?", "uncertainty-source")
    page = ctx.page
    if not src.get("rho"):
        page.paragraph(f"Not measured: {src.get('note', 'no labelled crops')}.", cls="note")
        return
    page.paragraph(f"Reading: {src.get('reading')}. With Uncertainty uses the spread of the MC samples as the "
                   "model uncertainty of a view; this checks whether that spread is larger where the crop's scores "
                   "fall farther from its class model.", cls="bottomline")
    page.table(["statistic", "value [95 % CI]", "chance"], source_rows(src), cls="uncertainty-source",
               caption=f"{src['n_crops']} labelled crops of {src['n_classes']} classes; spread = the sd of a crop's "
                       f"MC samples averaged over the GP components; |z| = |mean score − GP mean| / GP sd at the "
                       f"crop's true class and viewing direction, averaged over the components. 95 % CIs over "
                       f"{src.get('over', 'classes')} ({src.get('n_boot', 0)} bootstrap resamples).")
    if src.get("auroc_note"):
        page.paragraph(f"AUROC: {src['auroc_note']}.", cls="note")
    page.paragraph(f"Source of the MC samples: {src.get('source', '?')}. Drop-connect: {src.get('drop_connect', '?')}.",
                   cls="note")
