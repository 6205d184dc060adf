"""The claims scorecard at the top of the report: each claim of the paper (declared once, with the
paper's own numbers, sections, quotes and where the paper made it, in
``pipeline.evaluation.metrics.paper``), split by the run's setting into "the paper's claims" (tested
where the paper made them) and "questions beyond the paper" (tested elsewhere: they read "supported /
not supported in this setting", never that the paper's claim fails), our reading of
it as one paired comparison on one metric (directional, or equivalence within ±
``report.equivalence_margin_correct`` for the paper's "similar" correct ratios), our value with its
95 % CI and holds / fails / inconclusive, computed from that CI by the one outcome rule
(``reports.shared.checks.outcome_of``) or the equivalence rule (``records.equivalence``); plus the §5.3 simulation claims,
counted from the simulate stage's summary and linked to its page.

Reads the verdict records of ``summary.json`` (``population.records``: one per comparison and
metric) and, for runs written before them, the ``paired`` block; either way the outcome shown is
the one its interval gives, and every row is registered in the page's ledger, so a table further
down that labels the same statistic otherwise fails the build.
"""
from __future__ import annotations

import math
from pathlib import Path

from pipeline.evaluation.metrics.labels import comparison_key
from pipeline.evaluation.metrics.spec import higher_is_better
from pipeline.evaluation.metrics.paper import CLAIMS, TABLES_NOTE, Claim, run_setting, setting_label
from pipeline.evaluation.statistics.records import equivalence
from pipeline.infra.outputs import number
from reports.main.calibration import paired_value
from reports.main.context import ReportContext
from reports.shared.checks import outcome_of
from reports.shared.numbers import Estimate, plain
from reports.shared.records import varies_text
from pipeline.infra.outputs import read

CLAIM_WORDS = ("holds", "fails", "inconclusive")
EQUIVALENCE_WORDS = {"equivalent": "holds", "different": "fails", "not distinguishable": "inconclusive"}
DEFAULT_MARGIN = 0.05   # report.equivalence_margin_correct's default (pipeline/infra/config/evaluation.py)


def verdict_entry(pop: dict, comparison: str, metric: str) -> dict | None:
    """{value, lo, hi, n, over} of one paired comparison on one metric: from the verdict records
    where the run has them, else from the paired block (older runs)."""
    for r in pop.get("records") or []:
        if r.get("comparison") == comparison and r.get("metric") == metric:
            unb = bool(r.get("unbounded"))
            lo = number(r.get("lo"), -math.inf if unb else None, None)   # null: an unbounded end
            hi = number(r.get("hi"), math.inf if unb else None, None)
            out = {"value": r.get("value"), "lo": lo, "hi": hi, "n": r.get("n") or {},
                   "over": r.get("over") or ["targets", "tracks"]}
            if r.get("withheld"):   # no calibrated interval: no verdict (``withheld_status``)
                out["withheld"] = r["withheld"]
            elif r.get("outcome_holm"):   # a primary-family verdict: read off its Holm-widened interval
                out["holm"] = (number(r.get("lo_holm"), -math.inf, None), number(r.get("hi_holm"), math.inf, None))
            return out
    d = paired_value(pop, comparison, metric)
    if not d:
        return None
    return {"value": d.get("value"), "lo": d.get("ci_low"), "hi": d.get("ci_high"), "n": d.get("n") or {},
            "over": d.get("over") or ["targets", "tracks"]}


NOT_TESTED = "not tested here"
NO_VERDICT = "no verdict"


def setting_entry(pop: dict, c: Claim) -> tuple[dict | None, str]:
    """(the entry, why not) of a claim tested in one setting only (``Claim.setting``): the record the
    evaluate stage made for it (``population.paper_55``), or why the run could not test it."""
    p = pop.get("paper_55") or {}
    if p.get("comparison") != comparison_key(c.method, c.baseline) or p.get("metric") != c.metric:
        return None, "this run's summary holds no such test (an evaluate stage from before it)"
    r = p.get("record")
    if not r:
        return None, p.get("missing") or "no cells"
    return {"value": r.get("value"), "lo": number(r.get("lo"), -math.inf, None),
            "hi": number(r.get("hi"), math.inf, None), "n": r.get("n") or {}, "over": r.get("over") or [],
            **({"withheld": r["withheld"]} if r.get("withheld") else {})}, ""


def withheld_status(entry: dict | None) -> str:
    """'no verdict: no CI: <reason>' where the engine withheld the entry's interval, else ''."""
    return f"{NO_VERDICT}: no CI: {entry['withheld']}" if entry and entry.get("withheld") else ""


def tracks_entry(pop: dict, c: Claim) -> dict | None:
    """A percentile claim read over every track and realization of each method
    (``population.paper_55.mgr.all``); None for a run from before it."""
    pair = ((((pop.get("paper_55") or {}).get("mgr") or {}).get("all") or {}).get("paired") or {}).get(
        comparison_key(c.method, c.baseline))
    if not pair:
        return None
    e = pair["p95"]
    return {"value": e.get("value"), "lo": number(e.get("ci_low"), -math.inf, None),
            "hi": number(e.get("ci_high"), math.inf, None), "verdict": pair.get("verdict"),
            "no_verdict": pair.get("no_verdict")}


def claim_status(entry: dict | None, metric: str) -> str:
    """A directional claim: the side of 0 its interval lies on (the one outcome rule); for a record
    of the primary family, its Holm-adjusted interval (``multiplicity``)."""
    if entry is None:
        return "not measured"
    lo, hi = entry.get("holm") or (entry["lo"], entry["hi"])
    return outcome_of(lo, hi, higher_is_better(metric), words=CLAIM_WORDS)


def equivalence_status(entry: dict | None, margin: float) -> str:
    """A "similar" claim: holds when the whole interval lies within ±margin, fails when it lies
    wholly outside, else inconclusive (``records.equivalence``)."""
    if entry is None:
        return "not measured"
    return EQUIVALENCE_WORDS[equivalence(entry["lo"], entry["hi"], margin)]


def equivalence_margin(config: dict | None) -> float:
    """``report.equivalence_margin_correct`` of the run's resolved config (its default without one)."""
    v = ((config or {}).get("report") or {}).get("equivalence_margin_correct")
    return DEFAULT_MARGIN if v is None else float(v)


def paper_cell(c: Claim) -> str:
    """The paper's numbers for a claim, each with its section ('' -> says none is given)."""
    if not c.paper:
        return "none given for this comparison (Simple Bayes appears only in the §5.3 simulation, in words)"
    return "; ".join(n.cell() for n in c.paper)


def simulate_claims(run_dir: Path | None) -> list[dict]:
    """The §5.3 claims the simulate stage checked ([] where it did not run in this run folder)."""
    if run_dir is None:
        return []
    try:
        claims = read(Path(run_dir) / "simulate", "simulate", "summary").get("claims") or []
    except (OSError, ValueError, AttributeError):
        return []
    return [c for c in claims if isinstance(c, dict)]


IN_SETTING_WORDS = {"holds": "supported in this setting", "fails": "not supported in this setting",
                    "inconclusive": "inconclusive in this setting", "not measured": "not measured"}
VERDICT_CLAIM = {"better": "holds", "worse": "fails", "not distinguishable": "inconclusive"}


def beyond_reason(c: Claim, setting: str) -> str:
    """Why a test of ``c`` in ``setting`` is a question beyond the paper (not the paper's claim)."""
    if not c.made_in:
        return c.unclaimed
    if setting == "real_category":
        return ("category level, every test object unseen: the paper's classes are instances (§5.5.1), and §6 "
                "names category-level models a limitation; the paper made this claim in " + c.where())
    if setting == "real_instance":
        return ("real model uncertainty: the paper's real-image test (§5.5.2) assumed model uncertainty "
                "negligible; the paper made this claim in " + c.where())
    return "the paper made this claim in " + c.where()


def verdict_word(status: str, in_setting: bool) -> str:
    """holds / fails / inconclusive where the paper made the claim; outside that setting a finding
    about this setting ("not supported in this setting"), never "the paper's claim fails"."""
    if status.startswith((NOT_TESTED, NO_VERDICT)):
        return status
    return status if in_setting else IN_SETTING_WORDS[status]


def claim_row(ctx: ReportContext, c: Claim, pop: dict, margin: float) -> tuple[str, Estimate]:
    """The status (holds / fails / inconclusive / not measured / not tested here / no verdict) and
    estimate of one claim's test, registered in the page's ledger."""
    key = comparison_key(c.method, c.baseline)
    if c.setting != "all":
        e, why = setting_entry(pop, c)
        if e is None:
            return f"{NOT_TESTED} ({why})", Estimate(None)
        status = withheld_status(e) or claim_status(e, c.metric)
        ctx.ledger.register(("paired", key, c.metric, c.setting), e["value"], e["lo"], e["hi"],
                            label="" if e.get("withheld") else status,
                            where="claims scorecard", higher_is_better=higher_is_better(c.metric))
        return status, Estimate(e["value"], e["lo"], e["hi"], signed=True)
    t = tracks_entry(pop, c) if c.over_tracks else None
    if t is not None:
        status = VERDICT_CLAIM[t["verdict"]] if t["verdict"] else f"{NO_VERDICT}: {t['no_verdict']}"
        ctx.ledger.register(("over tracks", key, c.metric), t["value"], t["lo"], t["hi"],
                            label=status if t["verdict"] else "", where="claims scorecard",
                            higher_is_better=higher_is_better(c.metric))
        return status, Estimate(t["value"], t["lo"], t["hi"], signed=True)
    e = verdict_entry(pop, key, c.metric)
    equiv = c.reading == "equivalence"
    status = withheld_status(e) or (equivalence_status(e, margin) if equiv else claim_status(e, c.metric))
    est = Estimate(e["value"], e["lo"], e["hi"], signed=True) if e else Estimate(None)
    if e:
        # An equivalence verdict is about ±margin, not the side of 0: the number is registered
        # (one statistic across the page) without the directional label the ledger checks.
        holm = e.get("holm") if not equiv else None
        ctx.ledger.register(("paired", key, c.metric), e["value"], e["lo"], e["hi"],
                            label="" if equiv or holm or e.get("withheld") else status, where="claims scorecard",
                            higher_is_better=higher_is_better(c.metric))
        if holm:
            ctx.ledger.register(("holm", key, c.metric), e["value"], *holm, label=status,
                                where="claims scorecard (Holm)", higher_is_better=higher_is_better(c.metric))
    return status, est


def scorecard(ctx: ReportContext) -> None:
    """The paper's claims in the setting the paper made them, the questions beyond the paper, the §5.3
    line and the note on the paper's tables (inside the verdict section)."""
    pop = ctx.population
    if not pop:
        return
    margin = equivalence_margin(ctx.config)
    setting = run_setting(ctx.config)
    ours, beyond = [], []
    for c in CLAIMS:
        status, est = claim_row(ctx, c, pop, margin)
        inside = c.in_setting(setting)
        if inside:
            ours.append([c.text, f"{c.section}: “{c.quote}” ({c.where()})", c.how.format(margin=margin),
                         paper_cell(c), est, verdict_word(status, True)])
        else:
            beyond.append([c.question, beyond_reason(c, setting), c.how.format(margin=margin), est,
                           verdict_word(status, False)])
    def rule(yes: str, no: str) -> str:
        return (f"A directional test {yes} when the 95 % CI lies on the claimed side of 0, {no} on the other side, "
                "and is inconclusive when it contains 0 (for the primary comparisons, its Holm-adjusted interval: "
                "familywise 95 %, as the paired table shows); the 'similar' test "
                f"{yes} when the whole 95 % CI lies within ±{plain(margin)} (viewfuse's choice, "
                f"report.equivalence_margin_correct: the paper gives no margin), {no} "
                "when it lies wholly outside, else is inconclusive. The worst-case (MGR) test reads the 95th "
                "percentile of every track and realization of each method (its CI over targets) and gives no verdict "
                "where its CI spans more than one decade; the §5.5 test reads the biased-plus-randomized setting "
                "only, pose sampling alone (the poses-only variant) against Model Based, and reads 'not tested here' "
                f"where the run lacks it. The other CIs vary over {varies_text(pop)}, not over classifier training "
                "runs.")
    ctx.page.paragraph(f"This run's setting: {setting_label(setting)} (from its config). A claim is the paper's "
                       "only where the paper made it (simulation §5.3, rendered scenes §5.4, real images §5.5 with "
                       "localization uncertainty only and instance classes); tested elsewhere it is a question "
                       "beyond the paper, and its answer holds for this setting only.")
    if ours:
        ctx.page.table(["claim of the paper (in our words)", "where the paper says it", "our reading",
                        "paper's number (section; not our scene)", "ours: difference [95 % CI]", "verdict"],
                       ours, cls="scorecard",
                       caption="The paper's claims, in a setting where the paper made them, checked as paired "
                               "differences on the same (target, track, setting) cells. " + rule("holds", "fails"))
    else:
        ctx.page.paragraph("The paper's claims: none was made in this run's setting, so none is checked here; "
                           "each test below is a question beyond the paper.", cls="note")
    if beyond:
        ctx.page.table(["question beyond the paper", "why it is beyond the paper", "our reading",
                        "ours: difference [95 % CI]", "finding in this setting"], beyond, cls="scorecard",
                       caption="Questions beyond the paper: the same paired tests, outside the setting where the "
                               "paper made the claim (or on a comparison the paper does not make). A finding here "
                               "is about this setting, not a verdict on the paper's claim. "
                               + rule("is supported", "is not supported"))
    sim = simulate_claims(getattr(ctx.run, "run_dir", None))
    if sim:
        held = sum(1 for c in sim if c.get("holds") is True)
        firm = sum(1 for c in sim if c.get("holds") is True and c.get("ci_side") == "holds")
        ctx.page.paragraph(f"Simulation (§5.3): {held} of {len(sim)} of the paper's statements hold on this run's "
                           f"simulated track ({firm} with the whole 95 % CI on the claimed side); each is on the "
                           '<a href="../simulate/index.html">simulation page</a> with its statistic and CI.',
                           html=True)
    else:
        ctx.page.paragraph("Simulation (§5.3): the simulate stage has not run in this run folder, so its six "
                           "statements are not checked here (run the simulate stage; its page lists them).",
                           cls="note")
    ctx.page.paragraph(TABLES_NOTE, cls="note")
