"""The class-level contrast's section, "Instance vs category class models" (summary.json's
``population.contrast``, computed by the evaluate stage from the statistics engine; nothing is
recomputed here): per method and metric, the two arms' pooled values and the paired difference
instance − category with its 95 % CI, its verdict and its Holm-adjusted verdict."""
from __future__ import annotations

from pipeline.evaluation.metrics.labels import method_label
from pipeline.evaluation.metrics.spec import higher_is_better, metric_label
from pipeline.evaluation.statistics.records import WITHHELD
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate
from reports.shared.records import holm_text, join_words, over_text, statistic_text, varies_text

# The outcome of instance − category in the arms' words (the record's own label beside it).
ARM_WORDS = {"better": "instance level better", "worse": "category level better",
             "not distinguishable": "not distinguishable", WITHHELD: "no CI, no verdict (too few units)"}


def contrast_rows(block: dict, primary_only: bool = True) -> list[list]:
    """One row per (method, metric): the arms' pooled values, the difference [95 % CI], the verdict
    and the Holm-adjusted verdict ('—' outside the contrast's family)."""
    rows = []
    for r in block.get("rows") or []:
        if primary_only and not r.get("primary"):
            continue
        d = r["difference"]
        diff = {"value": d.get("value"), "ci_low": d.get("lo"), "ci_high": d.get("hi")}
        rows.append([method_label(r["method"], short=True), metric_label(r["metric"], short=True),
                     Estimate.of(r["instance"]), Estimate.of(r["category"]), Estimate.of(diff, signed=True),
                     ARM_WORDS.get(_outcome(d), _outcome(d)),
                     _holm(d)])
    return rows


def _outcome(d: dict) -> str:
    """The difference's outcome; "withheld" wherever it carries a reason (a summary from before the
    outcome said so kept "not distinguishable" beside it)."""
    return WITHHELD if d.get("withheld") else d["outcome"]


def _holm(d: dict) -> str:
    """``holm_text`` with the adjusted outcome in the arms' words; '—' outside the family."""
    oh = None if d.get("withheld") else d.get("outcome_holm")
    return ARM_WORDS.get(oh, oh) + holm_text(d)[len(oh):] if oh else "—"


def contrast_sentence(block: dict) -> str:
    """Which methods the instance level moves, on which primary metric, as the adjusted verdicts say;
    the comparisons withheld (no CI: ``design.withheld``) named with their reason, never counted
    among the not distinguishable ones."""
    prim = [r for r in block.get("rows") or [] if r.get("primary")]
    held = [r for r in prim if r["difference"].get("withheld")]
    moved = [r for r in prim if r not in held
             and (r["difference"].get("outcome_holm") or r["difference"]["outcome"]) in ("better", "worse")]
    rest = [r for r in prim if r not in held and r not in moved]
    said = [f"{_name(r)} ({ARM_WORDS[r['difference'].get('outcome_holm') or r['difference']['outcome']]})"
            for r in moved]
    if not held:
        if not moved:
            return ("On no primary metric does the class models' training set (instance against category level) "
                    "change any method's result distinguishably, after the Holm adjustment over this contrast's family.")
        return ("After the Holm adjustment over this contrast's family, the training set changes "
                + join_words(said) + "; every other primary comparison is not distinguishable.")
    why = join_words(list(dict.fromkeys(str(r["difference"]["withheld"]) for r in held)))
    no_verdict = (f"{'all ' + str(len(held)) + ' primary comparisons' if len(held) == len(prim) else join_words([_name(r) for r in held])} "
                  f"carr{'ies' if len(held) == 1 else 'y'} no CI and no verdict ({why})")
    if not moved and not rest:
        return ("No primary metric has a verdict on the class models' training set (instance against category "
                f"level): {no_verdict}.")
    tested = (f"the training set changes {join_words(said)}" if moved else
              "the training set (instance against category level) changes no method's result distinguishably")
    others = (f"; {join_words([_name(r) for r in rest])} {'is' if len(rest) == 1 else 'are'} not distinguishable"
              if moved and rest else "")
    return f"After the Holm adjustment over this contrast's family, {tested}{others}; {no_verdict}."


def _name(r: dict) -> str:
    return f"{method_label(r['method'], short=True)} on {metric_label(r['metric'], short=True)}"


def contrast_section(ctx: ReportContext) -> None:
    block = (ctx.population or {}).get("contrast")
    if not block or not block.get("rows"):
        return
    ctx.section("Instance vs category class models", "contrast")
    first = block["rows"][0]["difference"]
    for r in block["rows"]:
        d = r["difference"]
        key = ("contrast", r["method"], r["metric"])
        hib = higher_is_better(r["metric"])
        ctx.ledger.register(key, d.get("value"), d.get("lo"), d.get("hi"), label=_outcome(d),
                            where="class-level contrast", higher_is_better=hib)
        if d.get("outcome_holm") and not d.get("withheld"):
            ctx.ledger.register(("contrast-holm", r["method"], r["metric"]), d.get("value"), d.get("lo_holm"),
                                d.get("hi_holm"), label=d["outcome_holm"], where="class-level contrast (Holm)",
                                higher_is_better=hib)
    ctx.page.paragraph(
        "One run, two arms on the same frames, features, candidates, tracks and localization draws: the class "
        "models of the category arm are fitted on the category's other instances, those of the instance arm on the "
        "held-out instance itself at its training azimuths (the frames show the others). " + contrast_sentence(block),
        cls="context")
    head = ["method", "metric", "instance level", "category level", "instance − category [95 % CI]", "verdict",
            "Holm-adjusted verdict"]
    ctx.page.table(head, contrast_rows(block), cls="contrast",
                   caption=(f"Primary metrics ({join_words([metric_label(k, short=True) for k in block['primary']])}). "
                            f"Pooled values and the paired difference over the same (target, track, setting) cells; "
                            f"the difference is the {statistic_text(first)}; 95 % CIs resample "
                            f"{varies_text(first)} ({over_text(first)}; evaluate.statistics.cluster = "
                            f"{block.get('cluster')!r}). Holm-adjusted: every method on each primary metric of this "
                            "contrast as one family, familywise 95 % (each interval widened to its Holm step's level)."))
    explo = [r for r in block["rows"] if not r.get("primary")]
    if explo:
        ctx.page.table(head, contrast_rows({"rows": explo}, primary_only=False), cls="contrast-all",
                       collapsed=f"The {len(explo)} exploratory metrics' rows",
                       caption="The same contrast on the exploratory metrics (unadjusted).")
