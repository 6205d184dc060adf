"""The simulation page's claims parts: the paper's §5.3 claims table, the regime-sweep figure and
sentence, and the confident-error rate per step. Everything is read from ``summary.json``
(computed by ``pipeline.evaluation.simulation.claims`` and ``pipeline.evaluation.simulation.sweep`` in the stage); this
module only draws and words it.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from pipeline.evaluation.simulation.claims import verdict_word
from pipeline.evaluation.metrics.labels import method_color, method_label
from reports.shared.figures import new_subplots
from reports.shared.numbers import Estimate, fmt, plain

# Holds / fails, dark where the whole 95 % CI agrees with the verdict, pale where it spans the
# threshold (Okabe-Ito blue and vermillion, readable without colour vision by lightness).
STATE_COLORS = {("holds", "holds"): "#0072B2", ("holds", "spans"): "#9CC8E8",
                ("fails", "spans"): "#F2B8A0", ("fails", "fails"): "#D55E00"}
STATE_LABELS = {("holds", "holds"): "holds (whole CI)", ("holds", "spans"): "holds (CI spans threshold)",
                ("fails", "spans"): "fails (CI spans threshold)", ("fails", "fails"): "fails (whole CI)"}
SHORT = {
    "mb_low_at_step": "MU: >20 % of runs MB P(truth) < 0.2 at step {step}",
    "ours_p20_at_step": "MU: ours' P(truth) 20th pct > 0.33 at step {step}",
    "ours_more_correct": "MU: ours correct more often than MB",
    "sb_poor_at_inverse": "MU: SB poor at the inverse view (step {step})",
    "ours_graceful_bias": "bias: ours confidently wrong in ≤ 5 % of runs",
    "sb_well_bias": "bias: SB final correct ratio ≥ 0.9",
}


OP_TEXT = {">=": "≥", "<=": "≤"}


def state(rec: Mapping) -> tuple[str, str]:
    v = "holds" if rec["holds"] else "fails"
    side = rec["ci_side"] if rec["ci_side"] == v else "spans"
    return v, side


def claims_rows(claims: list[Mapping]) -> list[list]:
    """Rows of the claims table: paper wording, statistic, value [95 % CI], threshold, verdict."""
    return [[c["statement"] + (f" ({c['section']})" if c.get("section") else ""), c["statistic"] + (f" ({c['detail']})" if c.get("detail") else ""),
             Estimate(c["value"], c["ci_low"], c["ci_high"]), f"{OP_TEXT.get(c['op'], c['op'])} {plain(c['threshold'])}",
             verdict_word(c)]
            for c in claims]


CLAIMS_HEADER = ["claim (paper §5.3, Figs. 3 and 5)", "statistic", "value [95 % CI]", "holds if", "verdict"]


def claims_section(page, summary: Mapping[str, Any]) -> None:
    """The claims table at the top of the page, the sweep's sentence and, where the sweep found
    a better regime, the claims there."""
    claims = summary.get("claims") or []
    if not claims:
        return
    cp = summary.get("claim_params") or {}
    R = claims[0]["n"]
    page.section("The paper's claims", anchor="claims")
    held = sum(c["holds"] for c in claims)
    page.paragraph(f"{held} of {len(claims)} of the paper's §5.3 statements hold on this run "
                   f"({R} realizations per scenario; class models '{cp.get('model_confidence', '?')}', "
                   f"median predictive std along the track {fmt(cp.get('predictive_std'))}). "
                   "Each verdict is computed from the statistic; the CI is over realizations "
                   "(Wilson for shares, the order-statistic interval for percentiles, a seeded bootstrap "
                   "for the paired difference).")
    page.table(CLAIMS_HEADER, claims_rows(claims), cls="claims",
               caption="The paper's §5.3 statements in our words, each with its figure (declared once with the main "
                       "report's scorecard claims); the simulation is where the paper made them. 'step' is the 0-based "
                       f"track step {cp.get('step', '?')}; confident error: max P ≥ "
                       f"{plain(cp.get('confident_threshold'))} on a wrong class.")
    sw = summary.get("sweep")
    if sw:
        s = sw["summary"]
        mu_ok = bool(s.get("mu_all_hold_at"))
        page.paragraph(("Regime sweep: " if mu_ok else "Regime sweep — no setting of the grid reproduces "
                        "the paper's model-uncertainty scenario: ") + s["sentence"],
                       cls="" if mu_ok else "warn")
    br = summary.get("best_regime")
    if br:
        page.table(CLAIMS_HEADER, claims_rows(br["claims"]), cls="claims",
                   caption=f"The same claims where the sweep finds the most of them holding: GP noise variance "
                           f"{fmt(br['noise'])} (predictive std {fmt(br['predictive_std'])}), σ_max "
                           f"{plain(br['sigma_max'])}, {br['realizations']} realizations per scenario "
                           "(model_confidence = \"hand_made\" with that noise): "
                           f"{sum(c['holds'] for c in br['claims'])} of {len(br['claims'])} hold at this size.")


# -- figures --------------------------------------------------------------------------------------------
def fig_sweep(sweep: Mapping[str, Any], step: int):
    """One panel per claim: holds / fails over GP noise variance x σ_max, the default starred, the
    point where most claims hold circled."""
    from matplotlib.patches import Patch

    g = sweep["grid"]
    noise, sig = list(g["noise"]), list(g["sigma_max"])
    recs = sweep["records"]
    keys = list(dict.fromkeys(r["key"] for r in recs))
    by = {(r["key"], r["noise"], r["sigma_max"]): r for r in recs}
    ncol = min(3, len(keys))
    nrow = int(np.ceil(len(keys) / ncol))
    fig, axes = new_subplots(nrow, ncol, w=0.6 + 3.9 * ncol, h=0.9 + 3.3 * nrow, squeeze=False)
    d = sweep["default"]
    best = (sweep["summary"].get("best") or {})
    annotate = len(noise) * len(sig) <= 49
    sd = {}
    for r in recs:
        sd[r["noise"]] = r["predictive_std"]
    for i, k in enumerate(keys):
        ax = axes[i // ncol, i % ncol]
        for a, v in enumerate(noise):
            for b, s in enumerate(sig):
                r = by.get((k, v, s))
                if r is None:
                    continue
                ax.add_patch(_rect(a, b, STATE_COLORS[state(r)]))
                if annotate:
                    ax.text(a, b, fmt(r['value'], 2), ha="center", va="center", fontsize=6,
                            color="white" if state(r)[1] != "spans" else "#1d2330")
        _mark(ax, noise, sig, d["noise"], d["sigma_max"], "*", "default")
        if best:
            _mark(ax, noise, sig, best["noise"], best["sigma_max"], "o", "most claims hold")
        ax.set_xlim(-0.5, len(noise) - 0.5)
        ax.set_ylim(-0.5, len(sig) - 0.5)
        ax.set_xticks(range(len(noise)))
        ax.set_xticklabels([f"{fmt(v, 1)}\n{fmt(sd[v])}" for v in noise], fontsize=6.5)
        ax.set_yticks(range(len(sig)))
        ax.set_yticklabels([plain(s) for s in sig], fontsize=7)
        ax.set_title(SHORT.get(k, k).format(step=step), fontsize=8.5)
        ax.grid(False)
        if i % ncol == 0:
            ax.set_ylabel("σ_max")
        if i // ncol == nrow - 1:
            ax.set_xlabel("GP noise variance\n(median predictive std)", fontsize=8)
    for j in range(len(keys), nrow * ncol):
        axes[j // ncol, j % ncol].set_visible(False)
    handles = [Patch(color=c, label=STATE_LABELS[s]) for s, c in STATE_COLORS.items()]
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=7.5, frameon=False)
    fig.suptitle(f"The paper's claims over model confidence x σ_max ({g['name']} sweep, {g['realizations']} "
                 "realizations per point; ★ default, ○ where most claims hold)", fontsize=10)
    return fig


def _rect(a: int, b: int, color: str):
    from matplotlib.patches import Rectangle
    return Rectangle((a - 0.5, b - 0.5), 1, 1, color=color, lw=0)


def _mark(ax, noise, sig, v, s, marker, label):
    a = int(np.argmin([abs(np.log(x / v)) for x in noise]))
    b = int(np.argmin([abs(x - s) for x in sig]))
    ax.plot(a, b, marker, ms=13 if marker == "*" else 15, mfc="none" if marker == "o" else "#F0E442",
            mec="black", mew=1.2, label=label)


def fig_confident_errors(conf: Mapping[str, Mapping], threshold: float, title: str):
    """Confident-error rate per step and method, with its Wilson 95 % band over realizations."""
    fig, axes = new_subplots(1, 1, w=6.4, h=3.4)
    ax = axes[0, 0]
    for m, c in conf.items():
        k = np.arange(len(c["rate"]))
        ax.step(k, c["rate"], where="mid", color=method_color(m), label=method_label(m, short=True))
        ax.fill_between(k, c["ci_low"], c["ci_high"], step="mid", color=method_color(m), alpha=0.15, lw=0)
    from matplotlib.ticker import MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("track step k")
    ax.set_ylabel(f"share with max P ≥ {plain(threshold)}\non a wrong class")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(loc="best", fontsize=7)
    ax.set_title(title, fontsize=9.5)
    return fig
