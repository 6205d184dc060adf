"""Verdicts and pooled CIs of two evaluate summaries side by side (docs/results.md, "Verdicts
before/after the single statistics engine").

    python tools/verdicts_before_after.py BEFORE/summary.json AFTER/summary.json

Prints (markdown) every (comparison, metric) verdict whose outcome, statistic or number changed,
and, for the pooled values whose statistic did not change (mean-pooled metrics), the largest
shift of a CI end as a share of the CI's width.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def _before_rows(pop: dict) -> dict:
    return {(r["comparison"], r["metric"]): {"outcome": r["outcome"], "value": r.get("value"), "lo": r.get("ci_low"),
                                             "hi": r.get("ci_high"), "statistic": r.get("statistic", "mean over targets")}
            for r in pop.get("verdict_table") or []}


def _after_rows(pop: dict) -> dict:
    return {(r["comparison"], r["metric"]): {"outcome": r["outcome"], "value": r.get("value"), "lo": r.get("lo"),
                                             "hi": r.get("hi"), "statistic": r.get("pooling")}
            for r in pop.get("records") or []}


def _g(x) -> str:
    return "null" if x is None else f"{x:+.3g}"


def verdict_table(before: dict, after: dict) -> list[str]:
    b, a = _before_rows(before), _after_rows(after)
    out = ["| comparison | metric | before: outcome, statistic, value [CI] | after: outcome, pooling, value [CI] |",
           "|---|---|---|---|"]
    for key in list(b) + [k for k in a if k not in b]:
        x, y = b.get(key), a.get(key)
        if x and y and x["outcome"] == y["outcome"]:
            continue
        fx = f"{x['outcome']}, {x['statistic']}, {_g(x['value'])} [{_g(x['lo'])}, {_g(x['hi'])}]" if x else "—"
        fy = f"{y['outcome']}, {y['statistic']}, {_g(y['value'])} [{_g(y['lo'])}, {_g(y['hi'])}]" if y else "—"
        out.append(f"| {key[0]} | {key[1]} | {fx} | {fy} |")
    return out


def shown_table(before: dict, after: dict) -> list[str]:
    """The paired number the report's tables showed next to each label, where it changed: before,
    ``paired`` held the mean while the label came from the median for unbounded metrics."""
    out = ["| comparison | metric | before: label / number shown [CI] | after: label / number shown [CI] |",
           "|---|---|---|---|"]
    lab_b, lab_a = _before_rows(before), _after_rows(after)
    for key, per in (after.get("paired") or {}).items():
        for k, e in per.items():
            old = ((before.get("paired") or {}).get(key) or {}).get(k)
            if not old or old.get("value") is None or abs(old["value"] - e["value"]) <= 1e-9 * max(1.0, abs(e["value"])):
                continue
            lb, la = lab_b.get((key, k), {}).get("outcome", "—"), lab_a.get((key, k), {}).get("outcome", "—")
            out.append(f"| {key} | {k} | {lb} / {_g(old['value'])} [{_g(old.get('ci_low'))}, {_g(old.get('ci_high'))}] "
                       f"| {la} / {_g(e['value'])} [{_g(e.get('ci_low'))}, {_g(e.get('ci_high'))}] |")
    return out


def pooled_table(before: dict, after: dict) -> list[str]:
    """Pooled values whose statistic changed (unbounded metrics: the mean before, the median after)."""
    out = ["| method | metric | before (mean) [CI] | after (spec pooling) [CI] |", "|---|---|---|---|"]
    for m, per in (after.get("pooled") or {}).items():
        for k, e in per.items():
            old = ((before.get("pooled") or {}).get(m) or {}).get(k)
            if not old or e.get("pooling") != "median":
                continue
            out.append(f"| {m} | {k} | {_g(old['value'])} [{_g(old.get('ci_low'))}, {_g(old.get('ci_high'))}] "
                       f"| {e['pooling']}: {_g(e['value'])} [{_g(e.get('ci_low'))}, {_g(e.get('ci_high'))}] |")
    return out


def ci_shifts(before: dict, after: dict) -> tuple[float, str, int]:
    """Largest |CI end shift| / CI width over the pooled values and paired differences whose
    statistic is the mean in both summaries (same value); the entry; how many were compared."""
    worst, where, n = 0.0, "", 0
    pairs = [(blk, m, k, e) for blk in ("pooled", "paired") for m, per in (after.get(blk) or {}).items()
             for k, e in per.items()]
    for blk, m, k, e in pairs:
        old = ((before.get(blk) or {}).get(m) or {}).get(k)
        if not old or e.get("pooling") != "mean" or None in (old.get("ci_low"), old.get("ci_high"),
                                                              e.get("ci_low"), e.get("ci_high")):
            continue
        if old["value"] != old["value"] or abs(old["value"] - e["value"]) > 1e-9 * max(1.0, abs(e["value"])):
            continue  # a different statistic or value: not a reproduction check
        width = old["ci_high"] - old["ci_low"]
        if not width > 0 or not math.isfinite(width):
            continue
        n += 1
        s = max(abs(old["ci_low"] - e["ci_low"]), abs(old["ci_high"] - e["ci_high"])) / width
        if s > worst:
            worst, where = s, f"{blk} {m} {k}"
    return worst, where, n


def main(argv: list[str]) -> None:
    before, after = (json.loads(Path(a).read_text())["population"] for a in argv[:2])
    print("Verdicts whose outcome changed (or that exist on one side only):\n")
    print("\n".join(verdict_table(before, after)))
    print("\nNumbers shown next to a verdict label that changed:\n")
    print("\n".join(shown_table(before, after)))
    print("\nPooled values whose statistic changed:\n")
    print("\n".join(pooled_table(before, after)))
    worst, where, n = ci_shifts(before, after)
    print(f"\nMean-statistic CIs compared (pooled and paired): {n}; largest end shift {100 * worst:.1f} % of the CI "
          f"width ({where}).")


if __name__ == "__main__":
    main(sys.argv[1:])
