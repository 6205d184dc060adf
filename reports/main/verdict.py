"""The population sections of the main report: the verdict first, then the evidence per target,
then the diagnostics that drive it (GP fits at a bound, ablations). All numbers come from
``summary.json``'s ``population`` object; each is shown with its 95 % CI."""
from __future__ import annotations

from pipeline.evaluation.metrics.labels import (comparisons, comparison_key, comparison_label, method_label,
                                       ordered_methods)
from pipeline.evaluation.metrics.spec import higher_is_better, metric_label
from pipeline.evaluation.statistics.records import outcome
from pipeline.evaluation.statistics.resampler import wilson_interval
from pipeline.scoring.classifiers import describe_card, display_of
from reports.main.bottom_line import bottom_line, counts, no_ci_reason, scope_text
from reports.main.context import ReportContext
from reports.main.provided import filled, notes as provided_notes
from reports.shared.numbers import Estimate, fmt, percent
from reports.shared.records import (find, holm_text, outcome_clauses, outcome_text, records_of, select, sentence,
                                    sentences as render)
from reports.main.calibration import paired_value, pooled_value
from reports.main.reviewer import data_extra
from reports.main.scorecard import scorecard
from reports.shared.tables import bound_counts, hyperparameter_table
from pipeline.method.registry import get

# The verdict sentences shown on the first screen; the others (one per comparison and metric) sit
# in a collapsed list right under the pooled table.
HEADLINE = ("correct_final", "confident_error_final", "nll_final", "log10_mgr95_final")
ABLATION_SHOWN = ("correct_final", "log10_mgr95_final")   # the ablation table's two number columns
VERDICT_METRICS = ("correct_final", "confident_error_final", "nll_final", "correct_overall", "prob_truth_final",
                   "msde_final", "log10_mgr95_final")
TARGET_METRICS = ("correct_final", "prob_truth_final", "log10_mgr95_final")
PAIRED_METRICS = ("correct_final", "correct_overall", "prob_truth_final", "msde_final",
                  "log10_mgr75_final", "log10_mgr95_final")


def wilson(k: float, n: int, z: float = 1.96) -> Estimate:
    """A proportion k/n with its Wilson 95 % interval."""
    return Estimate(k / n, *wilson_interval(k, n, z))


def classifier_text(card: dict | None) -> str:
    if not card:
        return "classifier: unknown (classifier/card.json not found)"
    w = card.get("weights")
    if w == "synthetic":
        acc, n = card.get("accuracy"), card.get("val_images")
        acc_t = (wilson(round(float(acc) * n), int(n)).text() + f" on {n} held-out images" if acc is not None and n
                 else fmt(acc))
        seed = (card.get("training") or {}).get("seed")
        run = f"classifier.seed = {seed}" if seed is not None else "one seed"
        return (f"classifier: {display_of(card)} trained here on {card.get('num_classes', '?')} synthetic texture "
                f"families (the source domain), held-out top-1 {acc_t}; one training run ({run}): the CIs "
                f"cover targets and tracks, not training runs, which the seed study (viewfuse study) repeats with other seeds")
    return (describe_card(card)
            or f"classifier: {card.get('architecture', 'a network')} weights from {card.get('weights_file', 'a file')}")


def context_sentence(ctx: ReportContext) -> str:
    what = ctx.source.describe(ctx.config.get("data") or {}, data_extra(ctx))
    pop = ctx.population
    if pop:
        c = counts(pop)
        size = f"{scope_text(c)}; {len(pop.get('methods') or [])} methods"
        if c["single_track_targets"]:
            n1 = len(c['single_track_targets'])
            size += (f"; {n1} target{'s' if n1 != 1 else ''} with a single track "
                     f"({', '.join(c['single_track_targets'])}: no CI of their own)")
    else:
        size = f"one target ({ctx.ev.target or '?'}) on one track"
    return f"What was evaluated: {what}; {size}; {classifier_text(ctx.run.card)}."


def verdict_section(ctx: ReportContext) -> None:
    ctx.section("Verdict", "verdict")
    page, pop = ctx.page, ctx.population
    lines = bottom_line(pop or {}, ctx.run.card)
    head = 2 if (pop or {}).get("primary") else 1   # the declared primary comparison, then the exploratory verdicts
    register_primary(ctx, pop or {})
    for line in lines[:head]:
        page.paragraph(line, cls="bottomline")
    scorecard(ctx)  # the paper's claims, checked: on the first screen, right under the bottom line
    for line in lines[head:]:
        page.paragraph(line, cls="context")
    page.paragraph(context_sentence(ctx), cls="context")
    if not pop:
        msg = ("This run has no population evaluation: summary.json has no 'population' key (an evaluate "
               "stage from before the population evaluation wrote it), so there is no verdict. The numbers "
               "below come from one target on one track; their CIs cover only the localization noise, "
               "not other tracks, objects or classifiers. Rerun the evaluate stage for a verdict.")
        ctx.notes.append(msg)
        page.paragraph(msg, cls="warn")
        return
    # the sentences rendered from summary.json's records (reports/shared/records.py)
    recs = records_of(pop)
    sentences = render(recs)
    # the primary metrics' sentences up front (the bottom line speaks of them); the rest collapsed
    head = [sentence(r) for r in select(recs, primary=True)] or render(recs, HEADLINE) or sentences
    page.bullets(head or ["(the verdict list is empty)"], cls="verdict")
    methods = ordered_methods(pop.get("methods") or (pop.get("pooled") or {}).keys())
    pooled = pop.get("pooled") or {}
    shown = [k for k in VERDICT_METRICS if any(k in (pooled.get(m) or {}) for m in methods)]
    rows = [[method_label(m)] + [Estimate.of(pooled_value(pop, m, k)) for k in shown] for m in methods]
    for m in methods:
        for k in shown:
            ctx.ledger.register_estimate(("pooled", m, k), pooled_value(pop, m, k), where="pooled table")
    unit = str(pop.get("unit") or "")
    page.table(["method"] + [metric_label(k, short=True) for k in shown], rows, cls="summary pooled",
               caption=f"Pooled over the population: value [95 % CI]; NLL and log10 MGR (unbounded) as the median "
                       f"over targets of the target means. {unit[:1].upper() + unit[1:]} "
                       f"({pop.get('bootstrap', '?')} bootstrap resamples.) log10 MGR: 0 when the truth is the "
                       "most likely class. MSDE: lower is better.")
    every = list(dict.fromkeys(k for m in methods for k in (pooled.get(m) or {})))
    if len(every) > len(shown):
        page.table(["metric"] + [method_label(m, short=True) for m in methods],
                   # the statistic the verdict uses (pooled_value), as in the table above: one number per statistic
                   [[metric_label(k)] + [Estimate.of(pooled_value(pop, m, k)) for m in methods] for k in every],
                   cls="summary pooled-all", caption="Every pooled metric in summary.json, value [95 % CI].",
                   collapsed=f"All {len(every)} pooled metrics")
    if len(head) < len(sentences):
        page.bullets(sentences, cls="verdict-all", collapsed=f"All {len(sentences)} verdict sentences "
                                                             "(every metric, every comparison)")
    ceiling = _ceiling_line(pop)
    if ceiling:
        page.paragraph(ceiling, cls="note")
    page.paragraph(biased_rule(pop), cls="note")


def register_primary(ctx: ReportContext, pop: dict) -> None:
    """The declared primary comparison's number in the page's ledger (its label checked against
    its interval, one statistic wherever it recurs)."""
    p = pop.get("primary") or {}
    r = p.get("record")
    if r:
        ctx.ledger.register(("primary", r["comparison"], r["metric"], str(p.get("setting"))), r.get("value"),
                            r.get("lo"), r.get("hi"), label=r.get("outcome", ""), where="bottom line (primary)",
                            higher_is_better=r.get("better") == "higher")


def biased_rule(pop: dict) -> str:
    """How single-realization settings (the biased experiment) enter the pooled values."""
    c = counts(pop)
    single = c["single_realization_settings"]
    if not single:
        return "Every setting has several realizations; each enters the pooled values with the same weight."
    return (f"Rule for the single-realization setting{'s' if len(single) > 1 else ''} ({'; '.join(single)}): with "
            "one realization a cell's 'final-step percentile' of log10 MGR is that realization's value (the "
            "'all steps' percentiles run over its steps). It enters the pooled values and the verdict with the same "
            "weight as each randomized setting (a track's value is the mean over its settings); its own values "
            "are in its own row of the per-setting table under 'Where the method wins and loses'.")


def _ceiling_line(pop: dict) -> str:
    rows = [r for r in records_of(pop) if r.get("metric") == "correct_final"]
    if not rows:
        return ""
    r = rows[0]
    return (f"Difficulty: of {(r.get('n') or {}).get('cells', r.get('n_cells'))} (target, track, setting) cells, {r.get('ceiling_cells', 0)} have "
            f"both methods at a correct ratio of 1 (ceiling) and {r.get('floor_cells', 0)} at 0 (floor); "
            "the verdict rests on the others.")


def population_section(ctx: ReportContext) -> None:
    pop = ctx.population
    if not pop:
        return
    ctx.section("Where the method wins and loses", "population")
    page = ctx.page
    ctx.figure("forest.png", "Paired differences With Uncertainty − baseline on the same (target, track, "
                             "realization), per target and pooled, with 95 % bootstrap CIs over tracks. "
                             "A bar that crosses 0 is not distinguishable from no difference.")
    rows = _paired_rows(pop)
    recs = records_of(pop)
    for r in rows:
        ctx.ledger.register(("paired", r[-1][0], r[-1][1]), r[4].value, r[4].low, r[4].high, label=r[2],
                            where="paired table", higher_is_better=higher_is_better(r[-1][1]))
        rec = find(recs, *r[-1])
        if rec and rec.get("outcome_holm"):   # the adjusted verdict is read off its own, wider interval
            ctx.ledger.register(("holm", *r[-1]), rec.get("value"), rec.get("lo_holm"), rec.get("hi_holm"),
                                label=rec["outcome_holm"], where="paired table (Holm)",
                                higher_is_better=higher_is_better(r[-1][1]))
    fam = next((x.get("family") for x in recs if x.get("family")), None)
    page.table(["comparison", "metric", "outcome", "Holm-adjusted outcome", "difference [95 % CI]", "cells won",
                "cells lost", "cells"],
               [r[:-1] for r in rows], cls="paired",
               caption="Paired differences, pooled. Won/lost: share of (target, track, setting) cells where "
                       "With Uncertainty is strictly better / worse. "
                       + (f"Holm-adjusted: the {fam} primary comparisons (With Uncertainty against each baseline on "
                          "the primary metrics) as one family, familywise 95 % (each interval widened to its Holm "
                          "step's level); the bottom line and the scorecard read these; '—': exploratory, "
                          "unadjusted, or the declared primary comparison (evaluate.primary), which is tested alone "
                          "at 95 % and left out of the family." if fam else "No primary family: nothing is Holm-adjusted."))
    for note in method_notes(pop):
        page.paragraph(note, cls="note")
    if pop.get("per_target"):
        ctx.figure("per_target.png", "Each method per target and pooled, 95 % bootstrap CIs over tracks.")
        page.table(["target (tracks)", "method"] + [metric_label(k, short=True) for k in TARGET_METRICS],
                   _target_rows(pop), cls="per-target",
                   caption="Per target: value [95 % CI] over that target's tracks; a target with one track has "
                           "no CI of its own (the bootstrap resamples tracks), only its value.")
    else:
        note = "The results hold no per-target values (their per-target block is empty): nothing to show per target."
        ctx.notes.append(note)
        page.paragraph(note, cls="warn")
    _by_setting(ctx, pop)
    _difficulty(ctx, pop)
    for s in pop.get("skipped_targets") or []:
        page.paragraph(f"Target {s.get('target')} skipped: {s.get('reason')}", cls="warn")


def comparison_keys(pop: dict) -> list[str]:
    """The paired comparisons in summary.json: the known ones in their order, then any others."""
    have = list((pop.get("paired") or {}).keys())
    known = [comparison_key(m, b) for m, b in comparisons()]
    return [k for k in known if k in have] + [k for k in have if k not in known]


def _paired_rows(pop: dict) -> list[list]:
    outcome = {(r.get("comparison"), r.get("metric")): outcome_text(r) for r in records_of(pop)}
    holm = {(r.get("comparison"), r.get("metric")): holm_text(r) for r in records_of(pop) if r.get("outcome_holm")}
    rows = []
    for key in comparison_keys(pop):
        metrics = list(PAIRED_METRICS) + [k for k in (pop["paired"].get(key) or {}) if k not in PAIRED_METRICS
                                          and "overall" not in k]
        for metric in metrics:
            d = paired_value(pop, key, metric)   # the statistic the outcome is read from
            if not d:
                continue
            rows.append([comparison_label(key), metric_label(metric, short=True),
                         outcome.get((key, metric)) or _outcome(d, metric), holm.get((key, metric), "—"),
                         Estimate.of(d, signed=True),
                         _share(d.get("wins")), _share(d.get("losses")), d.get("n_cells"), (key, metric)])
    return rows


def method_notes(pop: dict) -> list[str]:
    """Each run method's note beside the paired comparisons (``FusionMethod.report_note``, from its
    summary.json block), its numbers formatted here."""

    out = []
    for key in pop.get("methods") or ():
        m = get(key)
        text, values = m.report_note(pop.get(key)) if m is not None else ("", {})
        if text:
            out.append(filled(text, values))
    return out


def _outcome(d: dict, metric: str) -> str:
    """better / worse / not distinguishable from the CI (the one rule, ``records.outcome``), where
    the records lack the row."""
    return outcome(d.get("ci_low"), d.get("ci_high"), higher_is_better(metric))


def _share(v) -> str:
    return percent(v)


def _target_rows(pop: dict) -> list[list]:
    per = pop.get("per_target") or {}
    n_tracks = counts(pop)["tracks_per_target"]
    rows = []
    for t in pop.get("targets") or per.keys():
        n = n_tracks.get(t)
        name = f"{t} ({n} track{'s' if n != 1 else ''})" if n else t
        for m in ordered_methods((per.get(t) or {}).keys()):
            ests = [(per[t][m] or {}).get(k) for k in TARGET_METRICS]
            why = next((no_ci_reason(e, n) for e in ests if e and no_ci_reason(e, n)), "")
            label = f"{t} ({why})" if why else name
            rows.append([label, method_label(m, short=True)] + [Estimate.of(e) for e in ests])
    return rows


def _by_setting(ctx: ReportContext, pop: dict) -> None:
    by = pop.get("by_setting") or {}
    reps = counts(pop)["realizations"]
    rows = []
    for setting, entry in by.items():
        for key in comparison_keys(pop):
            d = ((entry or {}).get("paired") or {}).get(key) or {}
            if d:
                rows.append([setting, reps.get(setting, "?"), comparison_label(key),
                             Estimate.of(d.get("correct_final"), True), Estimate.of(d.get("msde_final"), True),
                             Estimate.of(d.get("log10_mgr95_final"), True)])
    if rows:
        ctx.page.table(["setting", "realizations", "comparison", "Δ correct, final", "Δ MSDE, final",
                        "Δ log10 MGR 95%, final"], rows, cls="by-setting",
                       caption="Paired differences per localization setting (each setting on its own), 95 % CIs "
                               f"over {'scans, ' if 'scans' in str(pop.get('scope', '')) else ''}targets and tracks. With 1 realization the log10 MGR percentile is that "
                               "realization's value.")


def _difficulty(ctx: ReportContext, pop: dict) -> None:
    summ = (pop.get("difficulty") or {}).get("summary") or {}
    if not summ:
        return
    keys = ("min", "q25", "median", "q75", "max", "mean")
    ctx.page.table(["method"] + list(keys),
                   [[method_label(m, short=True)] + [(summ[m] or {}).get(k) for k in keys]
                    for m in ordered_methods(summ.keys())], cls="difficulty",
                   caption="Difficulty over the population's tracks: share of a track's views whose "
                           "single-view posterior ranks the target first (1 = every view alone is enough).")


def diagnostics_section(ctx: ReportContext) -> None:
    """GP fits at a bound, next to the ablations that measure what they do to the verdict."""
    ctx.section("What drives the result: GP fits and ablations", "diagnostics")
    page, index = ctx.page, ctx.run.index
    if not index:
        page.paragraph("models/index.json not found; GP fit diagnostics not shown.", cls="note")
    else:
        n = bound_counts(index)
        page.paragraph(
            f"{n['at_bound']} of {n['fits']} GP fits (class × component) ended with a hyperparameter at a bound; "
            f"in {n['noise_lower']} the noise variance sits at its lower bound. Such a fit treats its class's "
            "score as almost exactly known, so one off-model (domain-shifted) score makes that class nearly "
            "impossible: this is what produces very large log10 MGR values.")
        header, rows, _ = hyperparameter_table(index)
        if rows:
            page.table(header, rows, cls="hyperparameters", collapsed=f"All {len(rows)} fits (hyperparameters, "
                       "bound flags and optimizer messages)", caption="GP hyperparameters from models/index.json.")
    provided_notes(ctx)
    _ablations(ctx)


def _ablations(ctx: ReportContext) -> None:
    pop = ctx.population or {}
    abl = pop.get("ablations") or {}
    if not abl:
        ctx.page.paragraph("No ablations ran (evaluate.ablations is empty). Listing, e.g., "
                           "models.noise_floor=dropout measures how much of the verdict the fits at the "
                           "noise bound carry.", cls="note")
        return
    key = comparison_key(*comparisons()[0])
    rows = []
    for name, a in abl.items():
        if a.get("kind") == "attribution":  # its own section (sections_calibration)
            continue
        over = "; ".join(override_words(k, v) for k, v in (a.get("override") or {}).items()) or name
        ests = {m: paired_value(a, key, m) for m in HEADLINE}
        recs = [r for r in (find(records_of(a), key, m) for m in HEADLINE) if r is not None]
        shown = {m: Estimate.of(ests.get(m), True) for m in ABLATION_SHOWN}
        for m in HEADLINE:   # each shown number against its record; the others' outcome words too
            ctx.ledger.register_record(("ablation", name, key, m), shown.get(m), find(recs, key, m),
                                       where="ablation table")
        # short and computed: the headline metrics' outcomes, as the ablation's records word them
        said = "; ".join(outcome_clauses(recs, subject=False))
        rows.append([over, *shown.values(), said or "—"])
    ctx.page.table(["ablation", "Δ correct, final", "Δ log10 MGR 95 %, final", "outcomes with it"],
                   rows, cls="ablations", caption=f"Ablations on the same population: "
                   f"{comparison_label(key)}, 95 % CIs; each outcome is read off its paired difference's CI as in "
                   "the verdict (headline metrics here; every metric in the results file evaluate/summary.json).")


# Config overrides in plain words (the reproduce box and the configuration dump show the keys).
OVERRIDE_WORDS = {("evaluate.test_domain_variance", "cross_fit"): "the calibrated likelihood (an extra test-domain "
                                                                   "variance, cross-fitted)",
                  ("evaluate.test_domain_variance", "none"): "the paper's likelihood (GP variance alone)",
                  ("models.noise_floor", "dropout"): "GP noise floor at the dropout variance",
                  ("models.component_rule", "top_min"): "components chosen by their highest minimum score",
                  ("models.component_rule", "target_informative"): "components chosen as the most informative "
                                                                    "about the target"}


def override_words(key: str, value) -> str:
    return OVERRIDE_WORDS.get((key, str(value)), f"{key.split('.')[-1].replace('_', ' ')} set to "
                                                 f"{str(value).replace('_', ' ')}")
