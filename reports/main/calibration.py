"""Report sections on calibration: how wrong the class models are on the test domain, how
calibrated every method's posterior is (paper's likelihood and the calibrated one), and which
ingredient of With Uncertainty carries its difference to Model Based (attribution)."""
from __future__ import annotations

from pipeline.evaluation.metrics.labels import comparison_label, method_label, ordered_methods
from pipeline.evaluation.metrics.spec import metric_label
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt, plain
from reports.shared.records import find, records_of, sentences

CALIBRATED = "evaluate.test_domain_variance=cross_fit"
ATTRIBUTION = "attribution"
# The pooled table of the calibration section: each metric as its spec pools it (the verdict's statistic).
TABLE = ("correct_final", "confident_error_final", "ece_final", "msde_final", "nll_final", "log10_mgr95_final")


def pooled_value(block: dict, method: str, metric: str) -> dict | None:
    """The pooled value: the statistic the verdict uses (summary.json holds only that one)."""
    return pooled_of(block, method).get(metric)


def pooled_of(block: dict, method: str) -> dict:
    """A method's pooled entries as summary.json holds them (the source the ledger checks the
    calibration table's cells against)."""
    return ((block or {}).get("pooled") or {}).get(method) or {}


def paired_value(block: dict, comparison: str, metric: str) -> dict | None:
    """A paired difference as the verdict computes it (summary.json holds only the metric spec's
    statistic: the median over targets for unbounded metrics, else the mean), with the entry's
    win shares and cell counts."""
    return ((block.get("paired") or {}).get(comparison) or {}).get(metric)


def _header() -> list[str]:
    return ["likelihood", "method"] + [metric_label(k, short=True) + (" (median of targets)" if
                                                                     k.startswith(("nll", "log10")) else "")
                                       for k in TABLE]


def _rows(ctx: ReportContext, name: str, block: dict, key: tuple) -> list[list]:
    """The calibration table's rows of one block, each cell registered in the page's ledger against
    its pooled entry in summary.json (under ``key + (method, metric)``)."""
    rows = []
    for m in ordered_methods((block.get("pooled") or {}).keys()):
        shown = [Estimate.of(pooled_value(block, m, k)) for k in TABLE]
        ctx.ledger.register_row((*key, m), TABLE, shown, pooled_of(block, m), where="calibration table")
        rows.append([name, method_label(m, short=True)] + shown)
    return rows


def _sentences(block: dict, keys: tuple[str, ...], main: bool | None = None) -> list[str]:
    """The records' sentences for ``keys``; ``main`` True / False: only / all but With Uncertainty
    against Model Based (the comparison the calibration section is about)."""
    recs = records_of(block)
    if main is not None:
        recs = [r for r in recs if (r.get("comparison") == MAIN) == main]
    return sentences(recs, keys)


MAIN = "with_uncertainty-model_based"


def calibration_section(ctx: ReportContext) -> None:
    pop = ctx.population
    if not pop or "confident_error_final" not in ((pop.get("pooled") or {}).get("model_based") or {}):
        return
    ctx.section("Calibration: how often is each method confidently wrong?", "calibration")
    page = ctx.page
    thr, bins = pop.get("confident_threshold"), pop.get("ece_bins")
    cal = (pop.get("ablations") or {}).get(CALIBRATED)
    rows = _rows(ctx, "paper (GP predictive)", pop, ("pooled",)) + (
        _rows(ctx, "calibrated (+ test-domain variance)", cal, ("ablation", CALIBRATED, "pooled")) if cal else [])
    page.table(_header(), rows, cls="calibration pooled",
               caption=f"Pooled over the population, value [95 % CI] (targets, then tracks). Confident errors: share "
                       f"of posteriors with max P ≥ {plain(thr)} on a wrong class. ECE: top-label, {bins} equal-width bins "
                       "(torchmetrics' definition), over the pooled posteriors weighted as every pooled value. NLL = "
                       "−ln P(truth) and log10 MGR are unbounded: shown (and judged) as the median over targets of "
                       "the target means, so that no single target carries them.")
    keys = ("confident_error_final", "nll_final", "ece_final")
    page.bullets(_sentences(pop, keys, main=True), cls="verdict calibration")
    rest = _sentences(pop, keys, main=False)
    if rest:
        page.bullets(rest, cls="verdict calibration-rest", collapsed=f"The other comparisons ({len(rest)} sentences)")
    if cal:
        keys = ("correct_final", "confident_error_final", "nll_final", "log10_mgr95_final")
        page.bullets(["With the calibrated likelihood: " + s for s in _sentences(cal, keys, main=True)],
                     cls="verdict calibrated")
        rest = _sentences(cal, keys, main=False)
        if rest:
            page.bullets(["With the calibrated likelihood: " + s for s in rest], cls="verdict calibrated-rest",
                         collapsed=f"The other comparisons with the calibrated likelihood ({len(rest)} sentences)")
    ctx.figure("reliability.png", "Reliability diagram of the final posteriors: accuracy against confidence per "
                                  "bin (the diagonal is perfect calibration).")
    if cal:
        ctx.figure("reliability_calibrated.png", "The same with the calibrated likelihood.")


DOMAIN_KINDS = (("gp", "GP predictive (Model Based)"), ("gp_plus_dropout", "+ dropout variance (With Uncertainty)"),
                ("gp_calibrated", "+ test-domain variance (calibrated, cross-fitted)"),
                ("gp_t", "GP predictive as a Student-t (ν cross-fitted)"),
                ("gp_plus_dropout_t", "+ dropout variance as a Student-t (ν cross-fitted)"))


def overall(fit: dict, kind: str) -> dict:
    """One bank's pooled row of one likelihood (variance kind); {} where it has none."""
    return (fit.get(kind) or {}).get("overall") or {}


def domain_rows(dom: dict) -> list[list]:
    """The fit table's rows of one model bank: one per likelihood (variance kind) it holds."""
    rows = []
    for k, title in DOMAIN_KINDS:
        o = overall(dom, k)
        if o.get("n"):
            rows.append([title, o["n"], fmt(o["share_gt2"]), fmt(o["share_gt3"]), coverage_estimate(o),
                         fmt(o["abs_z_p90"]), fmt(o["abs_z_p99"])])
    return rows


def coverage_estimate(o: dict) -> Estimate:
    """A pooled row's 95 % coverage with its clustered 95 % CI (``domain.coverage``; none where
    withheld, or in a summary written before the CI existed)."""
    lo, hi = o.get("coverage95_ci") or (None, None)
    return Estimate(o.get("coverage95"), lo, hi)


FIT_ONLY = "fit only, no method results"   # the label of an evaluate.fit_spaces bank's rows


def domain_banks(dom: dict) -> list[tuple[str, dict]]:
    """(label, fit) of the main bank, then of each models.* ablation's bank, then of each fit-only
    bank (``evaluate.fit_spaces``: named by its space and labelled so, no cell ran on it)
    (``domain_fit.by_ablation``)."""
    def space(d):
        return f" ({d['score_space']} scores)" if d.get("score_space") else ""
    out = [("main" + space(dom), dom)]
    for a, d in sorted((dom.get("by_ablation") or {}).items(), key=lambda kv: (bool(kv[1].get("fit_only")), kv[0])):
        if d.get("n_crops"):
            out.append((f"{d.get('score_space') or a} scores ({FIT_ONLY})" if d.get("fit_only") else a + space(d), d))
    return out


COVERAGE_BAND = (0.92, 0.98)   # the band read as a fitting 95 % predictive interval (viewfuse's choice)
# The band verdict is read off the coverage's 95 % CI, never off the share alone.
BAND_RULE = ("inside when its whole 95 % CI lies in the band, above or below when its whole CI lies beyond it, "
             "else not distinguishable from an edge")


def band_verdict(o: dict) -> str | None:
    """"inside" | "above" | "below" | "undecided" (the CI straddles an edge of ``COVERAGE_BAND``: "not
    distinguishable from an edge of the band"), or
    None without a CI (withheld: no verdict)."""
    lo, hi = COVERAGE_BAND
    ci = o.get("coverage95_ci")
    if not ci or any(x is None or x != x for x in ci):
        return None
    a, b = float(ci[0]), float(ci[1])
    return ("inside" if lo <= a and b <= hi else "above" if a > hi else "below" if b < lo else "undecided")


def coverage_sentence(banks: list[tuple[str, dict]]) -> str:
    """Whether the default likelihood (the main bank's With Uncertainty predictive: GP + dropout
    variance, Gaussian) covers 92-98 %, read off its coverage's 95 % CI (``BAND_RULE``), and if not
    inside, which likelihoods of which bank of this run are (grouped by bank)."""
    lo, hi = COVERAGE_BAND
    o = overall(banks[0][1], "gp_plus_dropout")
    if o.get("coverage95") is None:
        return ""
    verdict = band_verdict(o)
    head = (f"The run's default predictive (+ dropout variance, {banks[0][0]}) covers {coverage_estimate(o).text()} "
            f"of the residuals in its 95 % interval")
    if verdict is None:
        why = o.get("coverage95_withheld") or "the results file holds no interval of it (a run before the CI)"
        return f"{head}; against the band {fmt(lo)}–{fmt(hi)} viewfuse reads as a fit: no CI, no verdict: {why}."
    where = {"inside": "inside the band", "above": "above the band", "below": "below the band",
             "undecided": "not distinguishable from an edge of the band"}[verdict]
    why = {"above": " (its intervals are wider than the scores spread)",
           "below": " (the scores spread wider than its intervals)"}.get(verdict, "")
    text = (f"{head} (95 % CI resampling {o.get('coverage95_over', 'the run')}): {where} "
            f"{fmt(lo)}–{fmt(hi)} viewfuse reads as a fit{why}; the rule: {BAND_RULE}.")
    if verdict != "inside":
        inside = [(bank, [t for k, t in DOMAIN_KINDS if band_verdict(overall(d, k)) == "inside"]) for bank, d in banks]
        inside = [f"{bank}: {', '.join(titles)}" for bank, titles in inside if titles]
        text += (" Inside it by that rule in this run: " + "; ".join(inside) + "." if inside
                 else " No bank or likelihood of this run lies inside it by that rule.")
    return text


# The fit table's number columns, in order (each row: the likelihood's title, then these).
DOMAIN_STATS = ("n", "share_gt2", "share_gt3", "coverage95", "abs_z_p90", "abs_z_p99")
KIND_OF = {title: k for k, title in DOMAIN_KINDS}


def register_fit_row(ledger, bank: str, fit: dict, row: list) -> None:
    """A fit-table row's numbers in the page's ledger beside its bank's pooled row in summary.json,
    both as the page writes them (``fmt``: the row holds text), one statistic per number."""
    kind = KIND_OF[row[0]]
    o = overall(fit, kind)
    source = {k: o.get(k) if k == "n" else fmt(o.get(k)) for k in DOMAIN_STATS}
    ci = o.get("coverage95_ci") or (None, None)
    source["coverage95"] = {"value": o.get("coverage95"), "ci_low": ci[0], "ci_high": ci[1]}   # the cell: an Estimate
    ledger.register_row(("domain fit", bank, kind), DOMAIN_STATS, row[1:], source, where="domain-fit table")


def _over(dom: dict) -> str:
    """What the main bank's coverage CIs resample (``coverage95_over``), or where none was made."""
    o = overall(dom, "gp_plus_dropout") or overall(dom, "gp")
    return o.get("coverage95_over") or "the run's units (this results file holds none)"


def domain_section(ctx: ReportContext) -> None:
    pop = ctx.population
    dom = (pop or {}).get("domain_fit") or {}
    if not dom.get("n_crops"):
        return
    ctx.section("Do the class models fit the test domain?", "domain-fit")
    page = ctx.page
    page.paragraph(
        f"{dom['n_crops']} AVD crops of modelled instances, poses from the {dom.get('pose_source', '?')}: each crop's "
        "mean dropout score against its own class's GP predictive at the true viewing direction, per component. "
        "A model that describes the room would leave 4.6 % of the standardized residuals beyond 2, 0.3 % beyond 3 "
        "and 95 % inside its 95 % interval.")
    banks = domain_banks(dom)
    rows = []
    for bank, d in banks:
        for row in domain_rows(d):   # each shown number against its bank's fit in summary.json
            register_fit_row(ctx.ledger, bank, d, row)
            rows.append(([bank] if len(banks) > 1 else []) + row)
    page.table((["models (score space)"] if len(banks) > 1 else []) +
               ["variance", "(crop, component)", "|z| > 2", "|z| > 3", "95 % coverage", "|z| p90", "|z| p99"], rows,
               cls="domain-fit", caption="Standardized residuals z = (score − GP mean) / sd, pooled over classes "
                                         "and components, in the models' score space (a Student-t row: each "
                                         "residual's t PIT on the Gaussian scale, so its coverage is the t's own "
                                         "95 % interval; per class and component in the results file "
                                         "evaluate/summary.json). 95 % coverage: the share [95 % CI], the CI "
                                         f"resampling {_over(dom)}, never the residuals (those of one crop, "
                                         "instance or scan are correlated); none where a level has under 8 units." +
                                         (" One row group per model bank, on the same crops: the main one, "
                                          "then each models.* ablation's own, then each score space of "
                                          "evaluate.fit_spaces (labelled \"fit only\": fitted for this "
                                          "table alone, no method ran on it)." if len(banks) > 1 else ""))
    sentence = coverage_sentence(banks)
    if sentence:
        page.paragraph(sentence)
    per = (dom.get("gp") or {}).get("per_class") or {}
    crow = []
    for c, comps in per.items():
        worst = max(comps.values(), key=lambda s: s.get("abs_z_p99") or 0)
        n = sum(s.get("n") or 0 for s in comps.values())
        gt3 = sum((s.get("share_gt3") or 0) * (s.get("n") or 0) for s in comps.values()) / max(n, 1)
        crow.append([c, n, fmt(gt3), fmt(worst.get("abs_z_p99"))])
    if crow:
        page.table(["class", "(crop, component)", "|z| > 3", "worst component's |z| p99"], crow, cls="domain-class",
                   collapsed="Per class (GP predictive alone)")
    tdv = dom.get("test_domain_variance") or {}
    if tdv:
        page.paragraph(f"Test-domain variance: {tdv.get('unit')}; {tdv.get('rule')}. Estimates per fold in "
                       "the results file evaluate/summary.json.", cls="note")
    ctx.figure("pit.png", "PIT histograms (flat = calibrated; a U shape = residuals wider than the model says).")


def attribution_section(ctx: ReportContext) -> None:
    att = ((ctx.population or {}).get("ablations") or {}).get(ATTRIBUTION)
    if not att:
        return
    ctx.section("Which ingredient carries the difference to Model Based?", "attribution")
    page = ctx.page
    rows = []
    keys = ("correct_final", "confident_error_final", "nll_final", "log10_mgr95_final")
    for comp, per in (att.get("paired") or {}).items():
        shown = [Estimate.of(per.get(k), signed=True) for k in keys]
        for k, e in zip(keys, shown):
            ctx.ledger.register_record(("ablation", ATTRIBUTION, comp, k), e, find(records_of(att), comp, k),
                                       where="attribution table")
        rows.append([comparison_label(comp)] + shown)
    page.table(["comparison"] + [metric_label(k, short=True) for k in keys], rows, cls="attribution",
               caption="With Uncertainty with one ingredient each, on the same cells and realizations: poses only "
                       "(dropout samples replaced by their mean) and dropout only (no pose sampling: σ = 0, one pose sample). "
                       "Paired differences [95 % CI]; NLL and log10 MGR as the median over targets.")
    page.bullets(_sentences(att, keys), cls="verdict attribution")
