"""The class-level contrast (``data.real_imagery.contrast``): each method's
instance arm against its category arm on the same cells, from the one statistics engine.

The evaluate stage runs the instance arm's bank as one more grid variant (``ARM``): its cells are
the default's (target, track) cells, with the same localization draws (``population.cell_rng``
does not read the variant), so a method's two arms pair cell by cell. Here each method of each arm
becomes one row set of a cell frame (``<method>@instance``, ``<method>@category``) and the engine's
``population_block`` takes the comparison instance − category per method: pooled values of each
arm, the paired difference with its 95 % interval clustered as ``evaluate.statistics.cluster``
says, the outcome, and a Holm adjustment over the contrast's own family (every method on each
primary metric). The pooled ECE is left out (it needs the arms' calibration sums).
"""
from __future__ import annotations

import pandas as pd

from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.metrics.labels import comparison_key, methods as method_keys
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.engine import population_block
from pipeline.infra.config.evaluation import cluster_of

ARM = "data.real_imagery.class_level=instance"   # the instance arm's grid variant (and its bank's key)
ARMS = ("instance", "category")
SEP = "@"
KEYS = ["target", "track", "setting"]


def arm_method(method: str, arm: str) -> str:
    return f"{method}{SEP}{arm}"


def check_paired(inst: pd.DataFrame, cat: pd.DataFrame, method: str) -> None:
    """The two arms of ``method`` hold the same (target, track, setting) cells, each on the same scan."""
    a = inst[inst["method"] == method].set_index(KEYS)
    b = cat[cat["method"] == method].set_index(KEYS)
    if set(a.index) != set(b.index):
        only = sorted(set(a.index) ^ set(b.index))
        raise ValueError(f"class-level contrast: {method}'s instance and category arms were not run on the same "
                         f"cells ({len(only)} unpaired, first {only[0]})")
    if "scan" in a and not (a["scan"].sort_index() == b["scan"].reindex(a.index).sort_index()).all():
        raise ValueError(f"class-level contrast: {method}: a (target, track) lies in another scan in the two arms")


def contrast_block(ev, table: pd.DataFrame, arm: str = ARM, default: str = DEFAULT) -> dict | None:
    """``population.contrast`` of ``summary.json`` from the cell table (one row per variant, target,
    track, setting, method): None without the arm's cells. {"methods", "metrics", "primary",
    "cluster", "over", "n", "rows": one per (method, metric) with each arm's pooled estimate and
    the paired record instance − category (Holm fields on the primary metrics)}."""
    inst = table[table["variant"] == arm]
    if inst.empty:
        return None
    cat = table[table["variant"] == default]
    present = set(inst["method"]) & set(cat["method"])
    methods = [m for m in method_keys() if m in present]
    if not methods:
        raise ValueError("class-level contrast: no method ran in both arms")
    for m in methods:
        check_paired(inst, cat, m)
    frames = []
    for name, part in zip(ARMS, (inst, cat)):
        sub = part[part["method"].isin(methods)].copy()
        sub["method"] = [arm_method(m, name) for m in sub["method"]]
        frames.append(sub)
    cells = pd.concat(frames, ignore_index=True).drop(columns=["variant"])
    metrics = [k for k in METRICS if k in cells]
    prim = tuple(ev.primary_metrics)
    pairs = [(arm_method(m, "instance"), arm_method(m, "category")) for m in methods]
    family = {comparison_key(a, b) for a, b in pairs}
    b = population_block(cells, [x for p in pairs for x in p], metrics, pairs, ev.bootstrap, ev.seed,
                         primary=prim, per_target=False, loto=False, cluster=cluster_of(ev),
                         family=lambda comparison, primary: bool(primary) and comparison in family)
    recs = {(r["comparison"], r["metric"]): r for r in b["records"]}
    rows = []
    for m, (a, c) in zip(methods, pairs):
        for k in metrics:
            r = recs.get((comparison_key(a, c), k))
            if r is None:
                continue
            rows.append({"method": m, "metric": k, "primary": k in prim, "instance": b["pooled"][a][k],
                         "category": b["pooled"][c][k], "difference": {**r, "method": m, "baseline": m}})
    first = rows[0]["difference"] if rows else {}
    return {"arm": arm, "methods": methods, "metrics": metrics, "primary": list(prim),
            "cluster": first.get("cluster", cluster_of(ev)), "over": first.get("over", []), "n": first.get("n", {}),
            "difference": "instance - category, on the same (target, track, setting) cells",
            "family": "Holm over every method on each primary metric of this contrast (familywise 95 %)",
            "rows": rows}
