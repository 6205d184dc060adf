"""The calibration suite's rows as the one markdown table of docs/calibration.md."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

from pipeline.evaluation.calibration.simulate import METRICS

SHORT = {"correct_final": "correct", "confident_error_final": "conf. err.", "prob_truth_final": "P(truth)"}


def _pct(s: Mapping | None) -> str:
    if not s:
        return "—"
    return f"{100 * s['share']:.1f} [{100 * s['lo']:.1f}, {100 * s['hi']:.1f}]"


def markdown(rows: Sequence[Mapping]) -> str:
    """One row per (design, regime, candidate): coverage of the planted difference per metric, the
    type-I error of one test, the Holm family's familywise error (with their Wilson 95 % intervals
    over the replications, in %), and the mean half-width over the one the estimates' spread needs."""
    cov = " | ".join(f"coverage {SHORT[k]}" for k in METRICS)
    head = (f"| design (config) | units | regime | interval | {cov} | type-I a test | familywise (Holm) "
            "| half-width / needed (correct) |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        units = " × ".join(f"{g} {k}" for k, g in r["levels"].items())
        if r.get("withheld"):
            verdict = f"withheld: {r['withheld'].split(':')[0]} (no interval, no verdict)"
            out.append(f"| {r['design']} ({r['stands_for']}) | {units} | {r['regime']} | {r['candidate']} | "
                       f"{verdict} |" + " — |" * (len(METRICS) + 2))
            continue
        cells = " | ".join(_pct(r["coverage"].get(k)) for k in METRICS)
        w = r["width"].get("correct_final")
        out.append(f"| {r['design']} ({r['stands_for']}) | {units} | {r['regime']} | {r['candidate']} | {cells} | "
                   f"{_pct(r['type1'])} | {_pct(r['fwer'])} (m = {r['family']}) | {'—' if w is None else f'{w:.2f}'} |")
    return "\n".join(out) + "\n"
