"""``viewfuse compare``: finished runs side by side (artifact folders, study seeds, ablation variants).

Reads only each run's ``evaluate/summary.json`` and its stages' ``manifest.json`` (for the config
each stage ran with); never the results tables, never code. An argument is a run folder (it holds
``evaluate/summary.json``) or a folder of run folders: a *seed group* when its runs differ only in
seed keys (``viewfuse study``'s ``study/``), pooled over its seeds; otherwise each run is its own
column. The comparison holds:

- the config keys whose values differ between the runs (only those, like ``dvc params diff``);
- the pooled metrics with their 95 % CIs, one column per run (and per seed group: pooled over
  seeds by the statistics engine, seeds -> targets -> tracks over the runs' ``population.cells``,
  the same bootstrap ``viewfuse study`` uses, see ``seed_pool``);
- the paired verdicts (better / worse / not distinguishable) side by side, a changed outcome
  (against the first column) marked.

Generic over methods, metrics and comparisons: whatever the summaries hold, in
``pipeline.evaluation.metrics.labels`` order.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.evaluation.metrics.labels import ordered_methods
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.records import outcome
from pipeline.infra.outputs import MANIFEST
from pipeline.infra.outputs import name as out_name
from reports.compare.planning import block_of as planning_block
from reports.compare.planning import rows as planning_rows
from reports.compare.read import RunFileError, manifest_sections, read_summary
from reports.shared.records import holm_text

STAGES = ("data", "classifier", "features", "models", "evaluate", "report")
SUMMARY = Path("evaluate") / out_name("evaluate", "summary")


class CompareError(ValueError):
    """A run that is missing or cannot be compared; the message names it."""


@dataclass
class Run:
    name: str
    path: Path
    population: dict
    config: dict[str, Any]                 # dotted key -> value, from the stage manifests
    notes: list[str] = field(default_factory=list)
    planning: dict | None = None           # summary.json's view-planning block, where it has one


@dataclass
class Column:
    """One column of the comparison: a run, or a seed group pooled over its seeds."""
    name: str
    runs: list[Run]
    pooled_over_seeds: bool = False
    pool: dict | None = None               # a seed group's pool (``seed_pool``), computed once


# -- reading ---------------------------------------------------------------------------------------
def _json(path: Path, run: str) -> Any:
    """summary.json read as untrusted input (reports.compare.read); errors name the run."""
    try:
        return read_summary(path)
    except FileNotFoundError:
        raise CompareError(f"run {run}: {path} not found") from None
    except RunFileError as e:
        raise CompareError(f"run {run}: {e}") from None


def flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dict -> {dotted key: leaf value} (lists stay values)."""
    if not isinstance(d, dict):
        return {prefix: d} if prefix else {}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def run_config(path: Path) -> tuple[dict[str, Any], list[str]]:
    """The config sections every stage's manifest recorded, merged (a section read by several
    stages is the same in each); notes for the manifests that are missing."""
    cfg: dict[str, Any] = {}
    missing = []
    unreadable = []
    for stage in STAGES:
        p = path / stage / MANIFEST
        sections, why = manifest_sections(p)
        if sections is None:
            if why == "missing":
                missing.append(stage)
            else:
                unreadable.append(f"{p} is unreadable ({why}): the {stage} stage's config is not compared")
            continue
        for sec, values in sections.items():
            cfg.update(flatten(values, sec))
    # The report stage is optional (presentation only); a run without any manifest says so once.
    missing = [s for s in missing if s != "report"]
    notes = [f"no readable manifest for stage(s) {', '.join(missing)}: their config is not compared"] if missing else []
    return cfg, notes + unreadable


def load_run(path: str | Path, name: str | None = None) -> Run:
    p = Path(path)
    label = name or p.name
    if not p.is_dir():
        raise CompareError(f"run {label}: folder {p} not found")
    summary = _json(p / SUMMARY, label)
    pop = summary.get("population") if isinstance(summary, dict) else None
    if not isinstance(pop, dict):
        raise CompareError(f"run {label}: {p / SUMMARY} has no 'population' (written by an older evaluate stage, "
                           "before the population evaluation): rerun `viewfuse evaluate` for that run")
    if not isinstance(pop.get("pooled"), dict):
        raise CompareError(f"run {label}: {p / SUMMARY} population has no 'pooled' values: incompatible version")
    cfg, notes = run_config(p)
    if "records" not in pop:
        notes.append("older summary format (no records): outcomes derived from the verdict table or the paired CIs")
    return Run(label, p, pop, cfg, notes, planning=planning_block(summary))


def _is_run(p: Path) -> bool:
    return (p / SUMMARY).is_file()


def resolve(args: list[str | Path]) -> list[Column]:
    """Arguments -> columns: a run folder is one column; a folder of runs is a seed group (one
    column per seed, then their pool) when its runs differ only in seed keys, else one column per run."""
    if not args:
        raise CompareError("compare: give at least one run folder (or a folder of runs)")
    cols: list[Column] = []
    args = list(args)
    names = [Path(a).name for a in args]
    for a in args:
        p = Path(a)
        if not p.exists():
            raise CompareError(f"run {p}: folder not found")
        if _is_run(p) or not p.is_dir():
            # two arguments with the same folder name (a/run, b/run) get their parent in the name
            name = p.name if names.count(p.name) == 1 else f"{p.parent.name}/{p.name}"
            cols.append(Column(name, [load_run(p, name)]))
            continue
        kids = sorted(c for c in p.iterdir() if c.is_dir() and _is_run(c))
        if not kids:
            # a run folder whose evaluate stage never finished: name what is missing
            if (p / "evaluate").exists() or any((p / s).is_dir() for s in STAGES):
                load_run(p)
            raise CompareError(f"run {p}: not a run folder ({SUMMARY} missing) and it holds no run folders")
        runs = [load_run(c, f"{p.name}/{c.name}") for c in kids]
        diff = config_diff(runs)
        if len(runs) > 1 and diff and all(k.split(".")[-1] == "seed" for k in diff):
            cols += [Column(r.name, [r]) for r in runs]
            cols.append(Column(f"{p.name}: pooled over {len(runs)} seeds", runs, pooled_over_seeds=True,
                               pool=seed_pool(runs)))
        else:
            cols += [Column(r.name, [r]) for r in runs]
    return cols


# -- what differs ----------------------------------------------------------------------------------
MISSING = "—"


def config_diff(runs: list[Run]) -> dict[str, list[Any]]:
    """{dotted key: [value per run]} for the keys whose values are not all equal (a key absent in
    a run counts as different and shows as '—')."""
    keys = sorted({k for r in runs for k in r.config})
    out = {}
    for k in keys:
        vals = [r.config.get(k, MISSING) for r in runs]
        if any(json.dumps(v, sort_keys=True, default=str) != json.dumps(vals[0], sort_keys=True, default=str)
               for v in vals[1:]):
            out[k] = vals
    return out


def unique_runs(cols: list[Column]) -> list[Run]:
    seen, out = set(), []
    for c in cols:
        for r in c.runs:
            if id(r) not in seen:
                seen.add(id(r))
                out.append(r)
    return out


# -- values ----------------------------------------------------------------------------------------
def seed_pool(runs: list[Run]) -> dict | None:
    """The engine's seed pool (``pipeline.evaluation.statistics.engine.seed_pool``) over a seed
    group's runs: pooled values and records over seeds, then targets, then tracks; None when a
    run's summary holds no cells."""
    from pipeline.evaluation.statistics.engine import seed_pool as pool  # heavy: pandas

    return pool({r.name: r.population for r in runs})


def metric_order(keys) -> list[str]:
    keys = list(dict.fromkeys(keys))
    return [k for k in METRICS if k in keys] + [k for k in keys if k not in METRICS]


def methods_of(cols: list[Column]) -> list[str]:
    return ordered_methods({m for c in cols for r in c.runs for m in r.population["pooled"]})


def metrics_of(cols: list[Column]) -> list[str]:
    return metric_order(k for c in cols for r in c.runs for d in r.population["pooled"].values() for k in d)


def pooled_value(col: Column, method: str, metric: str) -> dict | None:
    if not col.pooled_over_seeds:
        return (col.runs[0].population["pooled"].get(method) or {}).get(metric)
    return ((col.pool or {}).get("pooled", {}).get(method) or {}).get(metric)


def verdicts(run: Run) -> dict[tuple[str, str], dict]:
    """(comparison, metric) -> {"outcome", "value", "ci_low", "ci_high"}; from the records (older
    summaries: the verdict table, else the paired CIs)."""
    return _verdicts(run.population)


def _verdicts(pop: dict) -> dict[tuple[str, str], dict]:
    out = {}
    if pop.get("records"):
        for r in pop["records"]:
            # the primary family's Holm-adjusted verdict beside it, worded as on the main report
            out[(str(r["comparison"]), str(r["metric"]))] = {"outcome": r.get("outcome"), "value": r.get("value"),
                                                             "ci_low": r.get("lo"), "ci_high": r.get("hi"),
                                                             **({"withheld": r["withheld"]} if r.get("withheld")
                                                                else {}),
                                                             **({"outcome_holm": r["outcome_holm"],
                                                                 "holm": holm_text(r)} if r.get("outcome_holm") else {})}
        return out
    table = pop.get("verdict_table")
    if table:
        for r in table:
            out[(str(r["comparison"]), str(r["metric"]))] = {k: r.get(k) for k in ("outcome", "value", "ci_low",
                                                                                  "ci_high")}
        return out
    for key, per in (pop.get("paired") or {}).items():
        for metric, est in (per or {}).items():
            if isinstance(est, dict):
                higher = (METRICS[metric].higher_is_better if metric in METRICS
                          else est.get("better", "higher") == "higher")
                out[(key, metric)] = {"outcome": outcome(est.get("ci_low"), est.get("ci_high"), higher),
                                      **{k: est.get(k) for k in ("value", "ci_low", "ci_high")}}
    return out


def column_verdict(col: Column, key: tuple[str, str]) -> dict | None:
    vs = [verdicts(r).get(key) for r in col.runs]
    if not col.pooled_over_seeds:
        return vs[0]
    got = [v for v in vs if v]
    if not got:
        return None
    kinds = [v["outcome"] for v in got]
    same = len(set(kinds)) == 1 and len(got) == len(vs)
    pooled = _verdicts(col.pool or {}).get(key)
    if pooled is None:
        return {"outcome": "no pooled value (a run's summary has no cells)", "value": None, "ci_low": None,
                "ci_high": None, "held_for_every_seed": same}
    return {**pooled, "held_for_every_seed": same,
            "per_seed": kinds[0] if same else ", ".join(f"{k} ×{kinds.count(k)}" for k in dict.fromkeys(kinds))}


def verdict_keys(cols: list[Column]) -> list[tuple[str, str]]:
    keys = list(dict.fromkeys(k for c in cols for r in c.runs for k in verdicts(r)))
    order = {m: i for i, m in enumerate(metric_order(k[1] for k in keys))}
    comps = list(dict.fromkeys(k[0] for k in keys))
    return sorted(keys, key=lambda k: (comps.index(k[0]), order[k[1]]))


@dataclass
class Comparison:
    columns: list[Column]
    config: dict[str, list[Any]]           # key -> value per unique run
    runs: list[Run]
    methods: list[str]
    metrics: list[str]
    pooled: dict[tuple[str, str], list[dict | None]]          # (method, metric) -> per column
    verdicts: dict[tuple[str, str], list[dict | None]]        # (comparison, metric) -> per column
    changed: dict[tuple[str, str], list[bool]]                # outcome (or Holm-adjusted) differs from the first column
    notes: list[str]
    planning: list = field(default_factory=list)              # [(planner, metric, per column)]
    planning_paired: list = field(default_factory=list)       # [(comparison, metric, per column)]


def compare(args: list[str | Path]) -> Comparison:
    cols = resolve(args)
    runs = unique_runs(cols)
    methods, metrics = methods_of(cols), metrics_of(cols)
    pooled = {(m, k): [pooled_value(c, m, k) for c in cols] for k in metrics for m in methods}
    vkeys = verdict_keys(cols)
    ver = {k: [column_verdict(c, k) for c in cols] for k in vkeys}
    changed = {k: [bool(v and row[0] and (v["outcome"], v.get("outcome_holm")) != (row[0]["outcome"],
                                                                               row[0].get("outcome_holm")))
                   for v in row] for k, row in ver.items()}
    notes = [f"{r.name}: {n}" for r in runs for n in r.notes]
    plan_pooled, plan_paired = planning_rows([c.runs[0].planning if len(c.runs) == 1 and not c.pooled_over_seeds
                                              else None for c in cols])
    return Comparison(cols, config_diff(runs), runs, methods, metrics, pooled, ver, changed, notes,
                      plan_pooled, plan_paired)
