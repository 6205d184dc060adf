"""Power from variance components, and the paper's §5.5 setting: the power of the declared primary
comparison and what population would give it 80 % (summary.json's ``population.power``,
``pipeline.evaluation.statistics.power``),
and each method's pooled values in the ``biased_randomized`` setting beside the paper's figure.
Nothing is recomputed here."""
from __future__ import annotations


from pipeline.evaluation.metrics.labels import comparison_label, method_label
from pipeline.evaluation.metrics.spec import metric_label
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt, plain
from reports.shared.records import varies_text

# The paper's own figure for its §5.5 run (../shared/paper/numbers.md): Model Based ends with a wrong
# class at about 10 times the correct one's probability in around 10 % of runs.
PAPER_55 = ("the paper (§5.5.2, one track, Fig. 17): Model Based ends with a wrong class about 10 times as "
            "probable as the truth in around 10 % of runs; With Uncertainty classifies correctly")
SETTING_METRICS = ("correct_final", "wrong10_final", "confident_error_final", "log10_mgr95_final")


TERMS = (("object", "objects", "more objects (each with its scans)"),
         ("scan", "scans", "more scans (each with its objects)"),
         ("interaction", "cells", "more (object, scan) cells"),
         ("track", "tracks (cells × tracks per cell)", "more tracks (and realizations) per cell"))


def component_rows(power: dict) -> list[list]:
    """Term, its variance, its share of the pooled difference's variance now, what shrinks it."""
    c = power["components"]
    div = {"object": c["n_objects"], "scan": c["n_scans"], "interaction": c["n_cells"],
           "track": c["n_cells"] * c["tracks_per_cell"]}
    v_now = power["se_now"] ** 2
    rows = []
    for key, over, lever in TERMS:
        v = c.get(key)
        share = "—" if v is None or not v_now else f"{round(100 * v / div[key] / v_now)} %"
        rows.append([key, "not estimable" if v is None else fmt(v), f"÷ {plain(round(div[key], 1))} {over}", share,
                     lever])
    return rows


def need_rows(power: dict) -> list[list]:
    c, need, avail = power["components"], power.get("needed") or {}, power.get("available") or {}
    def cell(v, have=None):
        if v is None:
            return "none suffices (the other terms alone exceed the needed variance)"
        return str(v) + (f" ({have} in this run's data)" if have else "")
    return [["objects", str(c["n_objects"]), cell(need.get("objects"), avail.get("objects"))],
            ["scans", str(c["n_scans"]), cell(need.get("scans"), avail.get("scans"))],
            ["tracks per (object, scan) cell", fmt(c["tracks_per_cell"]), cell(need.get("tracks_per_cell"))]]


def reading_text(power: dict) -> str:
    r = power.get("reading")
    if r == "reached":
        return "80 % power is reached at this run's size."
    if r == "reachable by the config":
        ch = power["change"]
        now = f" (now {ch['now']})" if ch.get("now") else ""
        return (f"Reachable with this data: evaluate.tracks_per_target = {ch['evaluate.tracks_per_target']}{now}, "
                "if the scans hold that many distinct tracks per object (more realizations per cell shrink only the "
                "localization-noise part of the track term).")
    if r == "not reachable with this data":
        return (f"Not reachable with this data: with every object and scan it holds and unlimited tracks the standard "
                f"error cannot fall below {fmt(power['floor_se'])}, above the {fmt(power['se_needed'])} 80 % power "
                "needs.")
    return ("Reachable only with more objects or scans than this run evaluates (the needs above, each with the "
            "other counts as run).")


def _power_ci(power: dict) -> str:
    """'95 % CI 22–61 %: the variance read as a chi-square with the design's 10 degrees of freedom; ', or
    why there is none ('' for a summary from before the interval)."""
    ci = power.get("power_ci") or {}
    lo, hi = ci.get("ci_low"), ci.get("ci_high")
    if lo is None or hi is None or lo != lo or hi != hi:
        return "no CI: the design has no degrees of freedom for its variance; " if ci else ""
    return (f"95 % CI {round(100 * lo)}–{round(100 * hi)} %: the variance read as a chi-square with the "
            f"design's {plain(round(float(ci['df']), 1))} degrees of freedom; ")


def power_section(ctx: ReportContext) -> None:
    pop = ctx.population or {}
    power = pop.get("power")
    if not power or "components" not in power:   # a summary from before the variance components: nothing stated
        paper_setting(ctx, pop)
        return
    ctx.section("Power of the primary comparison", "power")
    what = (f"{comparison_label(str(power['comparison']))} on {metric_label(str(power['metric']), short=True)} "
            f"(setting: {power.get('setting')})")
    if power.get("reading") == "not estimable":
        ctx.page.paragraph(f"Power of the primary comparison, {what}: not estimable ({power.get('why')}).", cls="note")
        paper_setting(ctx, pop)
        return
    ctx.page.paragraph(
        f"Power of the primary comparison, {what}, to detect a true difference of ±{plain(power['effect'])}: "
        f"{round(100 * power['power_now'])} % at this run's size ({_power_ci(power)}standard error "
        f"{fmt(power['se_now'])}, two-sided "
        f"test at {plain(power['alpha'])}, not adjusted: the declared comparison alone); 80 % needs a standard error of "
        f"{fmt(power['se_needed'])}. {reading_text(power)}", cls="context")
    ctx.page.table(["term", "variance", "divided by", "share of the variance now", "what shrinks it"],
                   component_rows(power), cls="power-components",
                   caption="Variance components of the primary comparison's paired differences (one per object, "
                           "scan and track), moment estimators on the cell means (pipeline/evaluation/statistics/"
                           "power.py): point estimates; the power's interval above reads their sum's uncertainty "
                           "(Satterthwaite), the components and the needs below have none of their own, so the "
                           "projection is a plan, not a finding. "
                           "The track term holds the localization realizations too." +
                           "".join(" " + n[:1].upper() + n[1:] + "." for n in power["components"].get("notes") or []))
    ctx.page.table(["lever", "this run", "for 80 % power (each alone, the rest as run)"], need_rows(power),
                   cls="power", caption=f"What a true difference of ±{plain(power['effect'])} needs at 80 % power, "
                                        "two-sided 0.05.")
    paper_setting(ctx, pop)


def paper_setting(ctx: ReportContext, pop: dict) -> None:
    """Each method's pooled values in the biased_randomized setting(s), beside the paper's figure."""
    settings = [s for s in pop.get("settings") or [] if s.get("experiment") == "biased_randomized"]
    if not settings:
        return
    ctx.section("The paper's §5.5 setting", "paper-setting")
    over = (varies_text(pop) if pop.get("cluster") else
            "scans, targets and tracks" if "scans" in str(pop.get("scope", "")) else "targets and tracks")
    for s in settings:
        entry = (pop.get("by_setting") or {}).get(s["setting"]) or {}
        pooled = entry.get("pooled") or {}
        methods = [m for m in pop.get("methods") or pooled if m in pooled]
        rows = [[method_label(m)] + [Estimate.of(pooled[m].get(k)) for k in SETTING_METRICS] for m in methods]
        ctx.page.table(["method"] + [metric_label(k, short=True) for k in SETTING_METRICS], rows, cls="paper-setting",
                       caption=(f"Every pose biased by ({plain(s['bias_m'][0], signed=True)}, {plain(s['bias_m'][1], signed=True)}) m, then N(0, "
                                f"{plain(s['sigma_m'])} m) per axis around the biased estimate, With Uncertainty told σ = "
                                f"{plain(s['sigma_m'])} m; {s['realizations']} realizations per (target, track); 95 % CIs "
                                f"over {over}. Beside it, {PAPER_55}. The paper's event is the ten-to-one column (a "
                                "wrong class at least 10 times the truth: log10 MGR ≥ 1, ln MGR ≥ 2.30 on the paper's "
                                f"scale); a confident error is max P ≥ {fmt(pop.get('confident_threshold'))} on a "
                                "wrong class, a stricter event than the paper's."))
    mgr_over_tracks(ctx, ((pop.get("paper_55") or {}).get("mgr") or {}).get("biased_randomized") or {})


def mgr_over_tracks(ctx: ReportContext, block: dict) -> None:
    """The 75th and 95th percentiles of final log10 MGR over every track and realization of each
    method in the §5.5 setting, and the paired differences of the 95th (no verdict past a decade)."""
    if not block.get("methods"):
        return
    rows = [[method_label(m), Estimate.of(v.get("p75")), Estimate.of(v.get("p95")), "—"]
            for m, v in block["methods"].items()]
    for key, e in (block.get("paired") or {}).items():
        d = e.get("p95") or {}
        rows.append([f"{comparison_label(key)}: difference of the 95th percentiles", "—",
                     Estimate.of(d, signed=True), e.get("verdict") or f"no verdict: {e.get('no_verdict')}"])
        ctx.ledger.register(("over tracks", key, "log10_mgr95_final", "biased_randomized"), d.get("value"),
                            d.get("ci_low"), d.get("ci_high"), label=e.get("verdict") or "",
                            where="§5.5 setting, MGR over every track", higher_is_better=False)
    ctx.page.table(["method", "log10 MGR 75th percentile", "log10 MGR 95th percentile", "verdict"],
                   rows, cls="paper-setting-mgr",
                   caption=f"Final-step log10 MGR over every track and realization of a method in this setting "
                           f"({', '.join(str(n) for n in block.get('n_values', {}).values())} values), as the paper "
                           f"reads its runs (not a median of per-cell percentiles); 95 % CIs over "
                           f"{block.get('over', 'targets')}, {block.get('n_targets')} targets, following the run's "
                           "clustering as every mean's interval does. A difference whose CI spans more than one "
                           "decade gets no verdict."
                           + (f" No CI and no verdict here: {block['withheld']}." if block.get("withheld") else ""))
