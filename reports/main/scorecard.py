"""The claims scorecard at the top of the report: each claim of the paper about the AVD experiment
(§5.5), our reading of it as one paired comparison on one metric, the paper's own number where
we have it, our value with its 95 % CI and holds / fails / inconclusive, computed from that CI by
the one outcome rule (``reports.shared.checks.outcome_of``); plus the §5.3 simulation claims,
counted from the simulate stage's summary and linked to its page.

Reads the verdict records of ``summary.json`` (``population.records``: one per comparison and
metric) and, for runs written before them, the ``paired`` block; either way the outcome shown is
the one its interval gives, and every row is registered in the page's ledger, so a table further
down that labels the same statistic otherwise fails the build.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pipeline.evaluation.metrics.labels import comparison_key, comparison_label
from pipeline.evaluation.metrics.spec import higher_is_better
from pipeline.infra.outputs import number
from reports.main.calibration import paired_value
from reports.main.context import ReportContext
from reports.shared.checks import outcome_of
from reports.shared.numbers import Estimate

CLAIM_WORDS = ("holds", "fails", "inconclusive")


@dataclass(frozen=True)
class Claim:
    """One claim of the paper (paraphrased, §5.5) and the comparison that tests it."""
    text: str          # the paper's claim, in our words (the paper's own text is not copied)
    method: str
    baseline: str
    metric: str
    reading: str       # how we test it
    paper: str = ""    # the paper's own number, where it gives one and we have it (else '')


CLAIMS = (
    Claim("Under localization error, the method that models both model and localization uncertainty "
          "classifies correctly more often than Model Based.", "with_uncertainty", "model_based", "correct_final",
          "paired difference of the correct ratio at the final step, With Uncertainty − Model Based, > 0"),
    Claim("It is less often confidently wrong than Model Based, which trusts the pose estimate.",
          "with_uncertainty", "model_based", "confident_error_final",
          "paired difference of the confident-error rate at the final step, < 0"),
    Claim("Its worst cases are milder: a lower MGR (how far a wrong class beats the truth) than Model Based.",
          "with_uncertainty", "model_based", "log10_mgr95_final",
          "paired difference of the 95th percentile of log10 MGR at the final step, < 0"),
    Claim("Modelling the viewpoint dependence beats the view-independent Simple Bayes baseline.",
          "with_uncertainty", "simple_bayes", "correct_final",
          "paired difference of the correct ratio at the final step, With Uncertainty − Simple Bayes, > 0"),
)


def verdict_entry(pop: dict, comparison: str, metric: str) -> dict | None:
    """{value, lo, hi, n, over} of one paired comparison on one metric: from the verdict records
    where the run has them, else from the paired block (older runs)."""
    for r in pop.get("records") or []:
        if r.get("comparison") == comparison and r.get("metric") == metric:
            unb = bool(r.get("unbounded"))
            lo = number(r.get("lo"), -math.inf if unb else None, None)   # null: an unbounded end
            hi = number(r.get("hi"), math.inf if unb else None, None)
            return {"value": r.get("value"), "lo": lo, "hi": hi, "n": r.get("n") or {},
                    "over": r.get("over") or ["targets", "tracks"]}
    d = paired_value(pop, comparison, metric)
    if not d:
        return None
    return {"value": d.get("value"), "lo": d.get("ci_low"), "hi": d.get("ci_high"), "n": d.get("n") or {},
            "over": d.get("over") or ["targets", "tracks"]}


def claim_status(entry: dict | None, metric: str) -> str:
    if entry is None:
        return "not measured"
    return outcome_of(entry["lo"], entry["hi"], higher_is_better(metric), words=CLAIM_WORDS)


def simulate_claims(run_dir: Path | None) -> list[dict]:
    """The §5.3 claims the simulate stage checked ([] where it did not run in this run folder)."""
    if run_dir is None:
        return []
    from pipeline.infra.outputs import read
    try:
        claims = read(Path(run_dir) / "simulate", "simulate", "summary").get("claims") or []
    except (OSError, ValueError, AttributeError):
        return []
    return [c for c in claims if isinstance(c, dict)]


def scorecard(ctx: ReportContext) -> None:
    """The claims table, the §5.3 line and the note on the paper's tables (inside the verdict section)."""
    pop = ctx.population
    if not pop:
        return
    rows = []
    for c in CLAIMS:
        key = comparison_key(c.method, c.baseline)
        e = verdict_entry(pop, key, c.metric)
        status = claim_status(e, c.metric)
        est = Estimate(e["value"], e["lo"], e["hi"], signed=True) if e else Estimate(None)
        if e:
            ctx.ledger.register(("paired", key, c.metric), e["value"], e["lo"], e["hi"], label=status,
                                where="claims scorecard", higher_is_better=higher_is_better(c.metric))
        rows.append([c.text, c.reading, c.paper or "not transcribed", est, status])
    ctx.page.table(["claim of the paper (§5.5, in our words)", "our reading", "paper's number",
                    "ours: difference [95 % CI]", "verdict"], rows, cls="scorecard",
                   caption="The paper's claims, checked. "
                           f"{comparison_label(comparison_key(CLAIMS[0].method, CLAIMS[0].baseline))} and the other "
                           "comparisons as paired differences on the same (target, track, setting) cells. Holds: the "
                           "95 % CI lies on the claimed side of 0; fails: on the other side; inconclusive: it "
                           "contains 0. The CIs vary over targets and tracks, not over classifier training runs.")
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
    ctx.page.paragraph("The paper's Tables 1 and 2 report the AVD experiments on a handful of real tracks; their "
                       "numbers are not transcribed here (no copy of the paper's tables ships with this "
                       "repository), so the 'paper's number' column says so instead of guessing.", cls="note")
