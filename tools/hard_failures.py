"""The paper's §5.5 figure on a run: the share of runs whose final posterior puts a wrong class at
least ``--ratio`` times (default 10) as high as the truth, per method, in one experiment's settings
(default ``biased_randomized``), with 95 % CIs from the statistics engine (the run's hierarchy:
scans -> targets -> tracks where the run resampled scans) and the paired differences.

    python tools/hard_failures.py artifacts/real_full [--experiment biased_randomized] [--ratio 10]

Reads ``evaluate/results.parquet`` and ``evaluate/summary.json``; writes nothing.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import pandas as pd


def cells(results: pd.DataFrame, experiment: str, ratio: float) -> pd.DataFrame:
    """One row per (target, track, setting, method): the share of its realizations whose final
    log10 MGR is at least log10(ratio)."""
    r = results[(results["variant"] == "default") & (results["experiment"] == experiment)]
    if r.empty:
        raise SystemExit(f"results.parquet holds no {experiment!r} rows (is it in evaluate.experiments?)")
    final = r[r["step"] == r.groupby(["target", "track", "setting"])["step"].transform("max")]
    final = final.assign(hard=(final["log10_mgr"] >= math.log10(ratio)).astype(float))
    return final.groupby(["scan", "target", "track", "setting", "method"], sort=True)["hard"].mean().reset_index()


def main(argv: list[str]) -> int:
    from pipeline.evaluation.metrics.labels import comparisons
    from pipeline.evaluation.statistics.engine import population_block

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--experiment", default="biased_randomized")
    ap.add_argument("--ratio", type=float, default=10.0)
    a = ap.parse_args(argv)
    pop = json.loads((a.run / "evaluate" / "summary.json").read_text())["population"]
    r0 = pop["records"][0]
    cluster = r0.get("cluster") or ("scan" if "scans" in (r0.get("over") or []) else "target")
    table = cells(pd.read_parquet(a.run / "evaluate" / "results.parquet"), a.experiment, a.ratio)
    methods = [m for m in pop["methods"] if m in set(table["method"])]
    b = population_block(table.rename(columns={"hard": "hard_failure"}), methods, ["hard_failure"], comparisons(),
                         pop["bootstrap"], 0, per_target=False, loto=False, cluster=cluster)
    over = ", ".join(b["pooled"][methods[0]]["hard_failure"]["over"])
    print(f"share of runs with a wrong class >= {a.ratio:g} x the truth at the final step, {a.experiment} "
          f"(95 % CIs over {over}):")
    for m in methods:
        e = b["pooled"][m]["hard_failure"]
        print(f"  {m:<34} {e['value']:.3f} [{e['ci_low']:.3f}, {e['ci_high']:.3f}]")
    for key, per in b["paired"].items():
        e = per["hard_failure"]
        print(f"  {key:<34} {e['value']:+.3f} [{e['ci_low']:+.3f}, {e['ci_high']:+.3f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
