"""``viewfuse study``: does the verdict survive another classifier training run?

For every seed of ``study.seeds`` the chain classifier -> features -> models -> evaluate runs again
with ``classifier.seed = n`` under ``<run>/study/seed-<n>/`` (a config whose run folder points
there; the stage runner's manifests make a rerun skip finished seeds). The data stage is shared:
it is brought up to date once in the run folder and linked into every seed folder (its cache key
does not depend on the classifier seed). The seeds share the run's stage cache
(``run.stage_cache``), so a seed chain identical to one already finished is reused. Then
``study/summary.json`` and ``study/index.html`` put each seed's ``population.pooled`` and ``population.records`` (evaluate/summary.json) side by side
and say whether the verdict is the same for every seed: the same outcome (better / worse / not
distinguishable) for every (comparison, metric) record.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import time
from pathlib import Path
from typing import Any, Callable

from pipeline.infra.cache import write_json, write_text
from reports.study.page import render_html, study_sentence
from pipeline.infra.outputs import path as out_path
from pipeline.infra.outputs import read, read_manifest
from reports.compare.runs import CompareError, compare
from reports.compare.page import write_page
from stages.framework import stage_cache
from stages.framework.runner import ensure as ensure_stage

log = logging.getLogger("viewfuse.study")

CHAIN = ("classifier", "features", "models", "evaluate")
CHAIN_END = CHAIN[-1]


def study_dir(cfg) -> Path:
    return cfg.run_dir / "study"


def seed_config(cfg, seed: int):
    """The run config with classifier.seed = ``seed`` and its run folder at <run>/study/seed-<n>."""
    # The seeds keep the run's stage cache (not one under study/): a seed whose chain equals a
    # finished one anywhere (the run's own classifier seed, another run's study) reuses it.
    run = dataclasses.replace(cfg.run, artifacts=str(study_dir(cfg)), name=f"seed-{seed}",
                              stage_cache=str(stage_cache.root(cfg)))
    clf = dataclasses.replace(cfg.classifier, seed=int(seed))
    return dataclasses.replace(cfg, run=run, classifier=clf)


def share_data(cfg, scfg) -> None:
    """Link the run's data folder into a seed folder (relative link; nothing copied)."""
    src, dst = cfg.stage_dir("data"), scfg.stage_dir("data")
    if dst.exists() or dst.is_symlink():
        return
    dst.parent.mkdir(parents=True, exist_ok=True)
    os.symlink(os.path.relpath(src, dst.parent), dst, target_is_directory=True)


def _finished(scfg) -> str | None:
    m = read_manifest(scfg.stage_dir(CHAIN_END), missing=None, invalid=None)
    return m.get("finished") if isinstance(m, dict) else None


def seed_result(scfg, reused: bool) -> dict:
    """What the side-by-side page needs from one seed's folder (missing parts are None)."""
    out: dict[str, Any] = {"run_dir": str(scfg.run_dir), "reused": reused, "classifier_accuracy": None,
                           "classifier_accuracy_ci95": None,
                           "varying_fits": None, "varying_fits_at_bound": None,
                           "pooled": None, "records": None}
    c = read(scfg.stage_dir("classifier"), "classifier", "card", missing=None)
    if c is not None:
        out["classifier_accuracy"] = c.get("accuracy")
        out["classifier_accuracy_ci95"] = c.get("accuracy_ci95")
    idx = read(scfg.stage_dir("models"), "models", "index", missing=None)
    if idx is not None:  # the GP-fit health of this seed's scores: no varying fit at a bound
        thr = float(idx.get("varying_std_threshold", 0.01))
        out["varying_fits"] = sum(1 for d in idx.get("diagnostics", []) if d.get("train_std", 0.0) > thr)
        out["varying_fits_at_bound"] = idx.get("varying_fits_at_bound")
    summ = read(scfg.stage_dir(CHAIN_END), CHAIN_END, "summary", missing=None)
    if summ is not None:
        pop = summ.get("population") or {}
        for k in ("pooled", "records"):
            out[k] = pop.get(k)
        out["primary_metrics"] = pop.get("primary_metrics")
        out["bootstrap"] = pop.get("bootstrap")
        out["cells"] = pop.get("cells")  # for the seed-pooled bootstrap; not written per seed
    return out


def chain_seconds(scfg) -> dict[str, float | None]:
    """Seconds each stage of a seed's chain took when it last ran (its manifest), so a rerun that
    reuses the seed still reports what computing it cost."""
    out: dict[str, float | None] = {}
    for stage in CHAIN:
        m = read_manifest(scfg.stage_dir(stage), missing=None, invalid=None)
        out[stage] = m.get("seconds") if isinstance(m, dict) else None
    return out


def outcomes(result: dict) -> dict[str, str] | None:
    """(comparison / metric) -> outcome for one seed, from its records (an older summary: its
    ``verdict_table``); None without a population verdict."""
    table = result.get("records") or result.get("verdict_table")
    if table:
        return {f"{r['comparison']} / {r['metric']}": str(r["outcome"]) for r in table}
    return None


def summarize(results: dict[int, dict]) -> dict:
    """Side by side: per seed the pooled values and the verdict; whether the verdict agrees; and
    the verdict pooled over the seeds (the engine's one seed pool, at the seeds' own resample count)."""
    from pipeline.evaluation.statistics.engine import seed_pool  # heavy: pandas

    seeds = sorted(results)
    pooled = seed_pool({str(s): results[s] for s in seeds})
    per_seed = {str(s): {k: v for k, v in results[s].items() if k != "cells"} for s in seeds}
    outs = {s: outcomes(results[s]) for s in seeds}
    missing = [s for s in seeds if outs[s] is None]
    keys = sorted({k for o in outs.values() if o for k in o})
    table = {k: {str(s): (outs[s] or {}).get(k) for s in seeds} for k in keys}
    differ = sorted(k for k, row in table.items() if len(set(row.values())) > 1)
    held = {k: next(iter(row.values())) for k, row in table.items() if k not in differ and None not in row.values()}
    same = not missing and not differ
    sentence = study_sentence(seeds, missing, differ, len(keys), held)
    return {"seeds": seeds, "per_seed": per_seed, "outcomes": table, "differs_on": differ, "held": held,
            "missing": missing, "verdict_same": same, "sentence": sentence, "pooled_over_seeds": pooled}


def run_study(cfg, *, device: str = "auto", threads: int = 0, force: bool = False,
              ensure: Callable | None = None) -> dict:
    """Run (or reuse) every seed's chain, then write study/summary.json and study/index.html."""
    ensure = ensure_stage if ensure is None else ensure
    t0 = time.perf_counter()
    ensure(cfg, "data", device=device, threads=threads)
    results, timings = {}, {}
    for seed in cfg.study.seeds:
        scfg = seed_config(cfg, seed)
        share_data(cfg, scfg)
        before = _finished(scfg)
        t = time.perf_counter()
        print(f"[study] seed {seed}: {scfg.run_dir}", flush=True)
        ensure(scfg, CHAIN_END, force=force, device=device, threads=threads, _keys={})
        timings[str(seed)] = round(time.perf_counter() - t, 2)
        reused = before is not None and before == _finished(scfg)
        results[seed] = seed_result(scfg, reused)
    summary = summarize(results)
    summary["timings_s"] = {"per_seed": timings, "total": round(time.perf_counter() - t0, 2),
                            "chain_per_seed": {str(sd): chain_seconds(seed_config(cfg, sd)) for sd in cfg.study.seeds}}
    out = study_dir(cfg)
    write_json(out_path(out, "study", "summary"), summary)
    compared = write_compare(out, cfg.run.name, summary["sentence"])
    page = render_html(summary, cfg.run.name)
    if compared:  # the seeds side by side and pooled over seeds: viewfuse compare's page
        page = page.replace("</h1>", '</h1>\n<p><a href="compare/index.html">Every seed side by side, with the '
                                     "values pooled over seeds (viewfuse compare)</a></p>", 1)
    write_text(out_path(out, "study", "html"), page)
    print(f"[study] {summary['sentence']} -> {out_path(out, 'study', 'html')}", flush=True)
    return summary


def write_compare(out: Path, run_name: str, sentence: str) -> bool:
    """``study/compare/index.html``: ``viewfuse compare`` over the seed folders (a seed group)."""
    try:
        c = compare([out])
    except CompareError as e:
        log.warning("study: no comparison page: %s", e)
        return False
    write_page(c, out / "compare", title=f"viewfuse seed study: {run_name}", intro=[sentence])
    return True
