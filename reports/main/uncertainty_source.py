"""The report's section on the model-uncertainty source: does a crop's MC spread rank how far its
scores fall from its class model, within each class? Read from ``summary.json``
(``population.domain_fit.uncertainty_source``, computed by ``pipeline.evaluation.domain.source``);
this module only words it. The within-class figures lead; the figure pooled across classes is
shown labelled as such (it also measures which classes fit badly)."""
from __future__ import annotations

from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt


def _spread(sp: dict) -> str:
    if not sp or not sp.get("n_classes"):
        return "—"
    return (f"{fmt(sp['min'], signed=True)} to {fmt(sp['max'], signed=True)}, median {fmt(sp['median'], signed=True)} "
            f"({sp['n_classes']} classes where defined)")


def source_rows(src: dict) -> list[list]:
    """Rows: statistic, value [95 % CI], spread over classes, what chance reads. Within-class first."""
    w = src.get("within") or {}
    rows = []
    if w:
        rows += [["Spearman ρ (spread, |z|) within each class, pooled over classes by stratification",
                  Estimate.of(w.get("rho"), signed=True), _spread(w.get("rho_spread")), "0"],
                 [f"AUROC of the spread for {src.get('far', '|z| > 2')} within each class, pooled over classes by "
                  "stratification", Estimate.of(w.get("auroc")), _spread(w.get("auroc_spread")), "0.5"]]
    rows += [["Spearman ρ (spread, |z|) pooled across classes (also measures which classes fit badly)",
              Estimate.of(src.get("rho"), signed=True), "—", "0"],
             [f"AUROC of the spread for {src.get('far', '|z| > 2')} pooled across classes (share of crops: "
              f"{fmt(src.get('far_share'))})", Estimate.of(src.get("auroc")), "—", "0.5"]]
    return rows


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
                   "model uncertainty of a view; this checks whether, among crops of one class, that spread is larger "
                   "where the crop's scores fall farther from its class model.", cls="bottomline")
    w = src.get("within") or {}
    how = (f" Within-class: {w['how']}." if w.get("how") else "")
    page.table(["statistic", "value [95 % CI]", "spread over classes (min to max)", "chance"], source_rows(src),
               cls="uncertainty-source",
               caption=f"{src['n_crops']} labelled crops of {src['n_classes']} classes; spread = the sd of a crop's "
                       f"MC samples averaged over the GP components; |z| = |mean score − GP mean| / GP sd at the "
                       f"crop's true class and viewing direction, averaged over the components.{how} 95 % CIs by a "
                       f"bootstrap over {src.get('over', 'classes')} ({src.get('n_boot', 0)} resamples), for the "
                       "within-class and the pooled figures alike.")
    if w.get("max_class_far_share") is not None:
        top2 = w.get("top2_far_share")
        page.paragraph(f"Where the |z| > 2 crops come from: the class with the most has "
                       f"{round(100 * w['max_class_far_share'])} % of its crops beyond 2σ"
                       + (f"; the two classes with the most hold {round(100 * top2)} % of all of them"
                          if top2 is not None and top2 == top2 else "")
                       + ". Pooled across classes, a class whose model fails badly weighs on both statistics; "
                         "within each class it does not.", cls="note")
    if w.get("auroc_note"):
        page.paragraph(f"AUROC within class: {w['auroc_note']}.", cls="note")
    if src.get("auroc_note"):
        page.paragraph(f"AUROC (pooled across classes): {src['auroc_note']}.", cls="note")
    page.paragraph(f"Source of the MC samples: {src.get('source', '?')}. Drop-connect: {src.get('drop_connect', '?')}.",
                   cls="note")
