"""Power, stated, and the paper's §5.5 setting: what the population's intervals can decide and what
population would decide them (summary.json's ``population.power``, computed by the evaluate stage),
and each method's pooled values in the ``biased_randomized`` setting beside the paper's figure.
Nothing is recomputed here."""
from __future__ import annotations

import math

from pipeline.evaluation.metrics.labels import comparison_label, method_label
from pipeline.evaluation.metrics.spec import metric_label
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt, plain
from reports.shared.records import varies_text

# The paper's own figure for its §5.5 run (../shared/paper/numbers.md): Model Based ends with a wrong
# class at about 10 times the correct one's probability in around 10 % of runs.
PAPER_55 = ("the paper (§5.5.2, one track, Fig. 17): Model Based ends with a wrong class about 10 times as "
            "probable as the truth in around 10 % of runs; With Uncertainty classifies correctly")
SETTING_METRICS = ("correct_final", "confident_error_final", "log10_mgr95_final")


def _cost(seconds) -> str:
    if seconds is None or not math.isfinite(float(seconds)):
        return "—"
    s = float(seconds)
    return f"{fmt(s / 3600, 2)} h" if s >= 3600 else f"{plain(round(s / 60))} min"


def power_rows(power: dict) -> list[list]:
    rows = []
    for e in power.get("comparisons") or []:
        need = e.get("needed_units")
        cross = e.get("crossed_with")   # a crossed design: both top levels, scaled together
        now = f"{e.get('n_units')} {e.get('unit')}" + (f" × {e.get('n_scans')} {cross}" if cross else "")
        want = "—" if need is None else f"{need} {e.get('unit')}" + (f" × {e.get('needed_scans')} {cross}" if cross else "")
        rows.append([comparison_label(e["comparison"]), metric_label(e["metric"], short=True),
                     fmt(e.get("half_width")), now, "reached" if e.get("reached") else want,
                     "—" if e.get("needed_targets") is None else str(e["needed_targets"]),
                     _cost(e.get("cost_s")) if not e.get("reached") else "—"])
    return rows


def power_sentence(power: dict) -> str:
    """The widest primary half-width and what would bring it to the goal, in one sentence."""
    entries = [e for e in power.get("comparisons") or [] if e.get("half_width") is not None]
    if not entries:
        return ""
    goal = power.get("goal")
    open_ = [e for e in entries if not e.get("reached")]
    if not open_:
        return f"Every primary comparison's 95 % CI half-width is at most {fmt(goal)}."
    worst = max(open_, key=lambda e: (e.get("needed_units") or math.inf))
    need = worst.get("needed_units")
    targets = "" if worst["unit"] == "targets" else f"{worst.get('needed_targets')} targets, "
    crossed = bool(worst.get("crossed_with"))   # targets and scans scaled together
    unit = worst["unit"] + (f" crossed with {worst.get('needed_scans')} scans" if crossed else "")
    now = f" crossed with {worst.get('n_scans')} scans" if crossed else ""
    tail = (f"about {need} {unit} ({targets}{_cost(worst.get('cost_s'))} at this run's measured cost) "
            f"would bring it to {fmt(goal)}" if need is not None else
            "its interval is unbounded, so no population size follows from it")
    beyond = "".join(f" ({worst[k]})" for k in ("beyond", "caution") if worst.get(k))
    return (f"{len(open_)} of {len(entries)} primary comparisons have a 95 % CI half-width above {fmt(goal)}; the "
            f"widest, {comparison_label(worst['comparison'])} on {metric_label(worst['metric'], short=True)} "
            f"(half-width {fmt(worst['half_width'])} over {worst['n_units']} {worst['unit']}{now}): {tail}{beyond}.")


def priced(power: dict, seconds: float | None) -> dict:
    """``power`` with each projection's cost: the measured seconds of the chain times its scale
    (the block itself holds no measured time, so reruns write the same summary)."""
    if seconds is None or power.get("seconds_measured") is not None:
        return power
    comps = [{**e, "cost_s": None if e.get("scale") is None else float(seconds) * e["scale"]}
             for e in power.get("comparisons") or []]
    return {**power, "seconds_measured": float(seconds), "comparisons": comps}


def power_section(ctx: ReportContext) -> None:
    pop = ctx.population or {}
    power = pop.get("power")
    if power:
        power = priced(power, ((ctx.ev.summary or {}).get("timings_s") or {}).get("chain_total"))
        ctx.section("Power", "power")
        ctx.page.paragraph(power_sentence(power), cls="context")
        ctx.page.table(["comparison", "metric", "CI half-width", "units now", f"units for ≤ {fmt(power.get('goal'))}",
                        "targets for it", "projected cost"], power_rows(power), cls="power",
                       caption=f"Primary comparisons. The projection's unit is the intervals' top level "
                               f"(evaluate.statistics.cluster = {pop.get('cluster', 'target')!r}: they resample "
                               f"{varies_text(pop) if pop.get('cluster') else 'targets and tracks'}). "
                               f"Projection: {power.get('assumption')}. Measured cost: "
                               f"{_cost(power.get('seconds_measured'))} (data, features, models and this "
                               "population's evaluation).")
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
                                f"over {over}. Beside it, {PAPER_55}. A confident error here is max P ≥ "
                                f"{fmt(pop.get('confident_threshold'))} on a wrong class, a stricter test than the "
                                "paper's ten-to-one."))
