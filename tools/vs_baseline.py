"""Every method of every variant of a finished run against one baseline (default Simple Bayes), on
the correct ratio and the confident-error rate at the final step, with the statistics engine's
design intervals (``population_block``, the run's own clustering, bootstrap size and threshold).
The page pairs only With Uncertainty with each baseline; this answers "is any method, in any score
space or likelihood of the run, better than the baseline?" (docs/results.md). Unadjusted, exploratory.

    python tools/vs_baseline.py artifacts/real_category [--baseline simple_bayes] [--out FILE.json]

Reads ``evaluate/results.parquet`` (cells rebuilt as the evaluate stage reduces them: the mean over
realizations at each track's final step; the confident-error rule of ``metrics.spec``) and
``evaluate/summary.json`` (methods, settings, threshold, bootstrap, cluster); writes only ``--out``.
Checks itself against the run: With Uncertainty − the baseline in the main bank must equal the
page's record (printed).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

KEY = ["variant", "experiment", "setting", "scan", "target", "track", "method"]
METRICS = ("correct_final", "confident_error_final")
DEFAULT = "default"


def final_cells(results: pd.DataFrame, threshold: float) -> pd.DataFrame:
    """One row per (variant, experiment, setting, scan, target, track, method): the share of its
    realizations correct, and confidently wrong (``spec.confident_mask`` at ``threshold``), at the
    track's final step."""
    from pipeline.evaluation.metrics.spec import confident_mask

    r = results[results["step"] == results.groupby(KEY)["step"].transform("max")]
    r = r.assign(ce=confident_mask(r["confidence"].to_numpy(float), r["correct"].to_numpy(float),
                                   threshold).astype(float))
    return (r.groupby(KEY, sort=True).agg(correct_final=("correct", "mean"), confident_error_final=("ce", "mean"))
            .reset_index())


def against(cells: pd.DataFrame, methods_by_variant: dict[str, list[str]], baseline: str, n_boot: int,
            cluster: str, seed: int = 0) -> dict:
    """{variant: {"pooled": {method: {metric: estimate}}, "paired": {"method-baseline": {metric:
    estimate + "outcome"}}}}: each variant's methods pooled, and each against ``baseline`` of the
    same variant on the same cells, by ``population_block``; the outcome is ``records.outcome``
    (withheld where the engine withholds the interval)."""
    from pipeline.evaluation.statistics.engine import population_block
    from pipeline.evaluation.statistics.records import WITHHELD, outcome

    out = {}
    for variant, ms in methods_by_variant.items():
        tab = cells[(cells["variant"] == variant) & cells["method"].isin(ms)]
        ms = [m for m in ms if m in set(tab["method"])]
        if baseline not in ms:
            raise SystemExit(f"variant {variant!r}: no {baseline!r} rows in the results (methods: {', '.join(ms)})")
        pairs = tuple((m, baseline) for m in ms if m != baseline)
        b = population_block(tab, ms, list(METRICS), pairs, n_boot, seed, cluster=cluster, per_target=False,
                             loto=False)
        paired = {}
        for a, z in pairs:
            per = {}
            for k, e in b["paired"][f"{a}-{z}"].items():
                word = WITHHELD if e.get("withheld") else outcome(e.get("ci_low"), e.get("ci_high"),
                                                                 e["better"] == "higher")
                per[k] = {**e, "outcome": word}
            paired[f"{a}-{z}"] = per
        out[variant] = {"pooled": {m: dict(b["pooled"][m]) for m in ms}, "paired": paired}
    return out


def _ci(e: dict, signed: bool = False) -> str:
    f = "{:+.3f}" if signed else "{:.3f}"
    lo, hi = e.get("ci_low"), e.get("ci_high")
    iv = "no interval" if lo is None or hi is None or lo != lo else f"[{f.format(lo)}, {f.format(hi)}]"
    return f"{f.format(e['value'])} {iv}"


def table(res: dict, baseline: str) -> list[str]:
    """Markdown rows: variant, method, each metric's value [CI], its difference from the baseline
    [CI] and the outcome."""
    from pipeline.method import registry

    def label(m):
        c = registry.get(m)
        return c.label if c is not None else m

    rows = [f"| variant | method | correct ratio | − {label(baseline)} | confident-error rate | − {label(baseline)} |",
            "|---|---|---|---|---|---|"]
    for variant, r in res.items():
        first = True
        for m, pooled in r["pooled"].items():
            cells = []
            for k in METRICS:
                cells.append(_ci(pooled[k]))
                q = r["paired"].get(f"{m}-{baseline}")
                cells.append("(baseline)" if q is None else f"{_ci(q[k], signed=True)} {q[k]['outcome']}")
            rows.append(f"| {variant if first else ''} | {label(m)} | " + " | ".join(cells) + " |")
            first = False
    return rows


def run_methods(pop: dict) -> dict[str, list[str]]:
    """{variant: its methods} from ``summary.json``'s population: the main bank's, each ablation's
    (a score-space bank, a likelihood, ...) as the run evaluated it."""
    out = {DEFAULT: list(pop["methods"])}
    for v, a in (pop.get("ablations") or {}).items():
        if a.get("kind") != "attribution":   # the attribution variants are methods of the main bank
            out[v] = list(a.get("methods") or a["pooled"])
    return out


def main(argv: list[str]) -> int:
    from pipeline.evaluation.metrics.labels import comparison_key

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--baseline", default="simple_bayes")
    ap.add_argument("--out", type=Path, default=None, help="write the estimates as JSON here")
    a = ap.parse_args(argv)
    ev = a.run / "evaluate"
    pop = json.loads((ev / "summary.json").read_text())["population"]
    settings = {(s["experiment"], s["setting"]) for s in pop["settings"]}
    res = pd.read_parquet(ev / "results.parquet", columns=[*KEY, "realization", "step", "correct", "confidence"])
    res = res[[(e, s) in settings for e, s in zip(res["experiment"], res["setting"])]]
    cells = final_cells(res, float(pop["confident_threshold"]))
    out = against(cells, run_methods(pop), a.baseline, int(pop["bootstrap"]), pop.get("cluster") or "target")
    print("\n".join(table(out, a.baseline)))
    key = comparison_key("with_uncertainty", a.baseline)
    page = pop.get("paired", {}).get(key, {})
    for k in METRICS:
        if k in page and key in out[DEFAULT]["paired"]:
            print(f"check: {key} {k}: this tool {out[DEFAULT]['paired'][key][k]['value']:+.6f}, the page "
                  f"{page[k]['value']:+.6f}")
    if a.out:
        a.out.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
