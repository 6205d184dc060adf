"""Stage ``evaluate``: the population evaluation (every target x several tracks x the settings),
its statistics and verdict, and the single-track figures for the showcase track
(``pipeline.evaluation.grid.showcase``: where the methods disagree most at the final step).

I/O at the edges: read the model banks, the AVD features and the scans' geometry; the grid, the
experiments, the metrics and the statistics are pure functions in ``pipeline.evaluation.grid.population``,
``pipeline.evaluation.grid.experiments``, ``pipeline.evaluation.metrics.spec``, ``pipeline.evaluation.statistics.engine``
and ``pipeline.evaluation.grid.population_summary``; cells run on ``run.executor`` (local: in
forked worker processes, ``local_processes``).
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.evaluation.grid import experiments as E
from pipeline.method import call_guard
from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid import showcase as S
from pipeline.infra.cache import atomic_path, write_json
from pipeline.infra.config import Config, ConfigError
from pipeline.scoring.features import read_features
from pipeline.infra.outputs import name as out_name
from pipeline.infra.outputs import read as read_artifact
from pipeline.evaluation.grid.population import DEFAULT
from pipeline.evaluation.grid.banks import fit_bank_loaders, load_banks, load_provided, variant_provided
from pipeline.evaluation.grid.cell_reduce import reduce_cell
from pipeline.evaluation.grid.population_summary import cell_table, check_primary, method_blocks, population_summary
from pipeline.evaluation.metrics.results import ResultsWriter, metadata, result_block
from pipeline.evaluation.metrics.spec import Params
from pipeline.evaluation.domain.target_domain import TargetDomain, bank_fits, target_variances
from pipeline.scene.rays import TrackError, grid_step
from pipeline.evaluation.statistics.power import power_block
from pipeline.evaluation.grid.paper55 import paper_block
from pipeline.evaluation.grid.primary import check_declared, declared_block, paired_table
from stages.framework.roots import data_roots
from stages.framework.runner import stage_timings
from pipeline.evaluation.metrics.labels import comparisons, methods
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.evaluation.statistics.resampler import draw_seconds
from pipeline.infra.cost import Counts, Term, check
from pipeline.infra.progress import echo
from pipeline.infra.budget import budget, cap_workers, cores
from pipeline.infra.device import free_cores
from pipeline.infra.executor import executor_for
from pipeline.infra.executor_pool import LocalPool
from pipeline.method.fusion import engine_device
from pipeline.method.score_space import of_models

log = logging.getLogger("viewfuse.evaluate")
# The avd.parquet columns evaluate uses (checked present and typed on read).
AVD_COLUMNS = ("scan", "image", "instance", "difficulty", "box_x0", "box_x1", "cam_x", "cam_y", "heading", "pass")


def scan_geometry(cfg: Config, scans: list[str], avd: pd.DataFrame, skips) -> tuple[dict, dict, dict, dict]:
    """Per scan: (fx, cx) of the camera, the capture grid's spacing, {image: grid point id} (the
    move graph's stops, ``AVDScan.grid_points``) and the move graph {image: {move: image}} (the
    view planning's). The scan is read under the same skip policy
    as the features stage, so an entry features skipped does not stop this stage; geometry needs
    no frames, so a metadata-only copy (no jpg_rgb/) is read as one."""
    from loaders.avd import AVDScan  # heavy: scipy

    _, avd_root = data_roots(cfg)
    intr, steps, grids, moves = {}, {}, {}, {}
    for s in scans:
        scan = AVDScan(avd_root, s, skip=skips.log("avd", "AVD entry"), frames=(Path(avd_root) / s / "jpg_rgb").is_dir())
        K = scan.intrinsics()
        intr[s] = (float(K[0, 0]), float(K[0, 2]))
        grids[s] = scan.grid_points()
        moves[s] = {n: dict(img.moves) for n, img in scan.images.items()}
        rows = avd.loc[avd["scan"] == s, ["image", "cam_x", "cam_y"]]
        steps[s] = grid_step(rows[["cam_x", "cam_y"]].to_numpy(float),
                             P.view_grid_ids(rows["image"], grids[s], s))
    return intr, steps, grids, moves


def _chain_seconds(cfg: Config) -> float:
    """Seconds the upstream stages whose work grows with the population took (their manifests):
    with this stage's own so far, the measured cost that the power block scales."""

    return float(sum(v for k, v in stage_timings(cfg).items() if k in ("data", "features", "models") and v == v))


def single_track(cfg: Config, ctx, banks, first: P.Cell, domain: TargetDomain | None = None
                 ) -> tuple[list[dict], dict, dict[str, float]]:
    """The showcase track: sensitivity sweep, bias maps, GP rasters (paper figures; the arrays are
    written here). Returns the sensitivity rows (result blocks), the summary's entries
    ({"sensitivity": {setting: tables}}; {} without the sweep) and each part's seconds."""
    blocks: list[dict] = []
    summary: dict = {}
    timings: dict[str, float] = {}
    ev = cfg.evaluate
    models = P.cell_models(banks, first)   # the population's likelihood (calibrated, Student-t) on the showcase
    if "gp_models" in ev.experiments:
        t0 = time.perf_counter()
        rasters = E.gp_rasters(models)
        if domain is not None and not domain.table.empty:  # the observed AVD scores over the ±2σ band
            rasters.update(domain.ring_overlay(first.scan, first.classes, first.components))
        with atomic_path(ctx.out / out_name("evaluate", "gp_models")) as tmp, open(tmp, "wb") as f:
            np.savez(f, **rasters)
        timings["gp_models"] = time.perf_counter() - t0
    if "sensitivity" in ev.experiments:
        t0 = time.perf_counter()
        fixed, _ = P.pose_free_track(first, models, P.calibrated(first.models, first.test_variance))
        for s in P.sensitivity_settings(ev):
            posts = E.randomized(models, first.data, s.bias, s.sigma, s.realizations, s.n_x,
                                 P.cell_rng(ev.seed, first.target, first.track, s), var_floor=ev.variance_floor,
                                 fixed=fixed, provided=P.calibrated(first.models, first.test_variance),
                                 method_rng=P.method_streams(ev.seed, first.target, first.track, s))
            blocks.append(result_block(posts, first.truth, variant=DEFAULT, experiment=s.experiment, setting=s.label,
                                       sigma_m=float(s.sigma), bias_x=float(s.bias[0]), bias_y=float(s.bias[1]),
                                       scan=first.scan, target=first.target, track=first.track,
                                       candidates=",".join(first.classes), truth=first.truth))
            summary.setdefault("sensitivity", {})[s.label] = E.summarize(posts, first.truth, Params.of(ev))
        timings["sensitivity"] = time.perf_counter() - t0
    if "bias_maps" in ev.experiments:
        t0 = time.perf_counter()
        axis, post = E.bias_maps(models, first.data, ev.bias_maps.extent_m, ev.bias_maps.steps)
        with atomic_path(ctx.out / out_name("evaluate", "bias_maps")) as tmp, open(tmp, "wb") as f:
            np.savez(f, bias_x=axis, bias_y=axis, posterior=post, classes=np.array(first.classes),
                     images=np.array(first.data.images))
        timings["bias_maps"] = time.perf_counter() - t0
    return blocks, summary, timings


def check_budget(cfg: Config, n_targets: int, width: int, tracks: Sequence[int] = ()) -> float:
    """The cost model's check (``pipeline.infra.cost``) again, with the targets and tracks the
    features hold and the bootstrap's time from a timed small draw: refused, before the grid, when
    its memory or time does not fit. Returns (and says) how long the bootstrap's intervals will take."""

    ev = cfg.evaluate
    counts = Counts(targets=n_targets, tracks=width)
    check(cfg, "evaluate", counts, base=False)   # memory first: the timed draw below allocates
    # Intervals drawn: each metric for every method and paired comparison, pooled and per setting,
    # and per target for every method (a lower bound: ablations and the ECE come on top).
    settings = len(P.population_settings(ev))
    n_stats = len(METRICS) * ((len(methods()) + len(comparisons())) * (1 + settings) + n_targets * len(methods()))
    seconds = n_stats * draw_seconds([list(tracks) or [width] * n_targets], ev.bootstrap)
    if cfg.run.max_bootstrap_minutes and seconds > 60 * cfg.run.max_bootstrap_minutes:
        raise ConfigError(
            f"'evaluate.bootstrap' = {ev.bootstrap}: the {n_stats}+ bootstrap intervals over {n_targets} targets "
            f"would take about {seconds:.0f} s ({seconds / 60:.0f} min; scaled from a timed run of "
            f"{min(ev.bootstrap, 20000)} draws on this machine, a lower bound), over "
            f"'run.max_bootstrap_minutes' = {cfg.run.max_bootstrap_minutes:g}; lower 'evaluate.bootstrap' or raise "
            f"'run.max_bootstrap_minutes' (0 = no limit)")
    check(cfg, "evaluate", counts, base=False,
          extra=(Term(f"the {n_stats}+ bootstrap intervals (timed draw, scaled)", ("evaluate.bootstrap",),
                      seconds=seconds),))
    if seconds > 60:
        echo(f"[evaluate] evaluate.bootstrap = {ev.bootstrap}: the {n_stats}+ bootstrap intervals will take about "
             f"{seconds / 60:.0f} min (scaled from a timed run of 20000 draws; lower evaluate.bootstrap to shorten)")
    return seconds


def fusion_device(ctx, executor) -> tuple[str, bool]:
    """(device for the fusion engine in each cell, whether tasks ask the executor for a GPU).
    In this process: run.device resolved here (auto -> cuda when torch sees a GPU). On Ray: each
    task asks for a GPU where the cluster has one and resolves 'auto' in its worker."""
    want = ctx.device_request
    if executor.name == "local":
        return ("cpu" if want == "cpu" else ctx.device), False
    if want == "cuda" and not executor.gpus:
        raise RuntimeError("run.device = 'cuda' (or --device cuda) but the Ray cluster has no GPU")
    device = "cpu" if want == "cpu" or not executor.gpus else want
    return device, device != "cpu"


def local_processes(ctx) -> int:
    """Worker processes for the local executor's cells and planning episodes: the stage's threads
    where set (--threads, run.threads), else the cores free now (``free_cores``, as the features
    stage's scoring threads and the report's figure workers), as many as the memory budget holds
    beside this process (a forked worker's pages are this process's until it writes to them: at
    most about this process's size). The outputs do not depend on the count."""
    import psutil

    if ctx.device_request != "cpu" and ctx.device != "cpu":
        return 1   # the cells fuse on the GPU: its context does not survive a fork, and it is one device
    want = min(int(ctx.threads or ctx.cfg.run.threads or free_cores()), cores())
    if want <= 1:
        return 1
    rss = float(psutil.Process().memory_info().rss)
    return cap_workers("run.threads", want, rss, budget(ctx.cfg), parent=rss)


def population_statistics(cfg: Config, kept: list[dict], cells, tracks, skipped, domain_fit,
                          available: dict | None = None) -> tuple:
    """(the cells' table, the summary's population block): its CIs, verdicts and power
    (``available``: the objects and scans the run's data holds)."""
    table = cell_table(kept)
    population = population_summary(cfg, table, cells, kept, tracks, skipped, domain_fit)
    population.update(method_blocks(cfg, cells, kept, population))
    p = population["primary"] = declared_block(cfg.evaluate, table)   # evaluate.primary, read first by the report
    diffs = paired_table(table, p["method"], p["baseline"], p["metric"], p["settings"])
    population["power"] = power_block(diffs, p, available=available, tracks_per_target=cfg.evaluate.tracks_per_target)
    population["paper_55"] = paper_block(cfg.evaluate, table, cells, kept)   # the paper's §5.5 test, as it ran it
    return table, population


def run(ctx) -> str:
    cfg: Config = ctx.cfg
    ev = cfg.evaluate
    t_start = time.perf_counter()
    check_primary(ev.primary_metrics)   # a config error before any cell runs
    check_declared(ev)
    banks, indexes = load_banks(ctx.input("models"), tuple(ev.ablations))
    provided = load_provided(ctx.input("models"), cfg)
    avd_path = ctx.input("features") / out_name("features", "avd")
    avd, scores, meta = read_features(avd_path, "avd", AVD_COLUMNS)
    if avd.empty:
        raise TrackError(f"{avd_path} holds no AVD box: nothing to evaluate")
    scans = sorted(avd["scan"].unique())
    intr, steps, grids, moves = scan_geometry(cfg, scans, avd, ctx.skips)
    truth = read_artifact(ctx.input("data"), "data", "truth", missing=None)
    cells, tracks, skipped = P.build_cells(ev, avd, scores, indexes, truth, intr, steps, provided, grids,
                                           variant_provided(ctx.input("models"), cfg))
    per_target = Counter(i.target for i in tracks)
    check_budget(cfg, len(per_target), max(per_target.values(), default=1), list(per_target.values()))
    for sk in skipped:
        log.warning("target %s skipped%s: %s", sk["target"], f" in {sk['scan']}" if "scan" in sk else "", sk["reason"])
    for t in sorted({c.target for c in cells}):
        mine = [i for i in tracks if i.target == t]
        log.info("target %s: %d track(s) in %s; candidates %s", t, len(mine), ", ".join(sorted({i.scan for i in mine})),
                 ", ".join(next(c.classes for c in cells if c.target == t)))
    t0 = time.perf_counter()
    domain = TargetDomain(cfg, avd, scores, banks[DEFAULT], truth, intr, sorted({c.target for c in cells}), scans)
    cells = target_variances(cells, domain, cfg)
    domain_fit = domain.summary()   # and each models.* ablation's and fit-only bank's pooled rows
    domain_fit["by_ablation"] = bank_fits(cfg, avd, scores, banks, truth, intr, sorted({c.target for c in cells}),
                                          scans, fit_bank_loaders(ctx.input("models"), cfg, indexes[DEFAULT]))
    domain_s = time.perf_counter() - t0

    timings: dict[str, float] = {"domain_fit": domain_s}
    # The cells stream: each is reduced as it finishes (its rows written, its metrics, calibration
    # sums and, for the default variant, its single-track tables kept) and its posteriors dropped,
    # so memory does not grow with the population (configs/paper_grade.toml). The results file's
    # metadata names the showcase track, known only after the grid: the writer takes it at the end.
    kept: list[dict] = []
    fusion: dict[str, float] = {}   # per method: its fusion calls' seconds, summed over the cells
    t_reduce = t_write = 0.0
    t0 = time.perf_counter()
    writer = ResultsWriter(ctx.out / out_name("evaluate", "results"))
    # every method call in the cells and episodes (here, or in the workers forked below) is stopped
    # and named after run.method_seconds
    old_limit = call_guard.set_time_limit(cfg.run.method_seconds)
    with writer, contextlib.ExitStack() as undo:
        undo.callback(call_guard.set_time_limit, old_limit)
        processes = local_processes(ctx) if cfg.run.executor == "local" else 1
        executor = LocalPool(processes) if processes > 1 else executor_for(cfg)
        try:
            device, gpu = fusion_device(ctx, executor)
            cells = [dataclasses.replace(c, device=device) for c in cells]
            plan_tasks, t_plan = None, 0.0
            if cfg.plan.enabled:   # built before the workers fork, so that they inherit them
                from pipeline.planning.population import build_tasks  # heavy: pandas

                t1 = time.perf_counter()
                plan_tasks = build_tasks(cells, tracks, avd, scores, moves, ev, cfg.plan, of_models(banks[DEFAULT]))
                t_plan = time.perf_counter() - t1
            if isinstance(executor, LocalPool):
                executor.inherit(cells, plan_tasks or [])
            done = executor.imap(P.run_cell, cells, shared=banks, desc="evaluate: cells", unit="cell",
                                 total=len(cells), gpu=gpu)
            for i, res in enumerate(done):   # to its end: the executor records its tasks there
                cell = cells[i]
                t1 = time.perf_counter()
                for m, sec in res.get("seconds", {}).items():
                    fusion[m] = fusion.get(m, 0.0) + sec
                k, blocks = reduce_cell(cell, res, Params.of(ev), tables=cell.variant == DEFAULT)
                t2 = time.perf_counter()
                for b in blocks:
                    writer.write(b)
                kept.append(k)
                t_reduce += t2 - t1
                t_write += time.perf_counter() - t2
            timings["population"] = time.perf_counter() - t0 - t_reduce - t_write
            timings.update({f"population_{m}": sec for m, sec in fusion.items()})
            timings["cell_reduce"] = t_reduce
            log.info("population: %d cells (%d targets x %d tracks x %d variant(s)) in %.1f s", len(cells),
                     len({c.target for c in cells}), len(tracks), len(indexes), timings["population"])
            planning, plan_times, job = None, {}, None
            # With worker processes the planning episodes run there while this process does the
            # population's statistics (a thread waits on them): the two share no state, and each
            # gives the same bytes either way.
            with ThreadPoolExecutor(1) as beside:
                if cfg.plan.enabled:
                    from pipeline.planning.evaluation import run_planning  # heavy: pandas

                    def plan_part():
                        t1 = time.perf_counter()
                        out = run_planning(cfg, plan_tasks, banks, executor, ctx.out / out_name("evaluate", "planning"))
                        return out, time.perf_counter() - t1 + t_plan
                    if isinstance(executor, LocalPool):
                        job = beside.submit(plan_part)
                    else:
                        (planning, plan_times), timings["planning"] = plan_part()
                t1 = time.perf_counter()
                table, population = population_statistics(cfg, kept, cells, tracks, skipped, domain_fit, {
                    "objects": int(avd["instance"].nunique()), "scans": len(scans)})
                timings["statistics"] = time.perf_counter() - t1
                if job is not None:
                    (planning, plan_times), timings["planning"] = job.result()
                timings.update(plan_times)
        finally:
            executor.close()
        timings["chain_total"] = _chain_seconds(cfg) + time.perf_counter() - t_start

        # The showcase track (pipeline/evaluation/grid/showcase.py: where the methods disagree most): its
        # biased/randomized tables, kept from the grid, plus the single-track figures.
        chosen = S.choose(table)
        at = next(i for i, c in enumerate(cells)
                  if c.variant == DEFAULT and c.target == chosen["target"] and c.track == chosen["track"])
        first = cells[at]
        population["showcase"] = chosen
        summary: dict = {}
        for (experiment, label), tables in kept[at]["tables"].items():
            summary.setdefault(experiment, {})[label] = tables

        with engine_device("cpu" if ctx.device_request == "cpu" else "auto"):
            blocks, entries, times = single_track(cfg, ctx, banks, first, domain)
        for b in blocks:
            writer.write(b)
        summary.update(entries)
        timings.update(times)
        writer.metadata = metadata(config_hash=cfg.section_hash("evaluate"), seed=str(ev.seed),
                                   classes=list(first.classes), target=first.target, track=str(first.track))
        t0 = time.perf_counter()
    timings["writing"] = t_write + time.perf_counter() - t0
    n_rows = writer.rows
    info = next(t for t in tracks if t.target == first.target and t.track == first.track).as_dict()
    obj_truth = P.truth_entry(truth, first.scan, first.target)
    info.update(classes=list(first.classes), yaw_deg=float(np.degrees(first.data.yaw)),
                gp_inputs=first.data.inputs(first.data.cam_xy).tolist(),
                n_views_seeing_target=int(len(P.target_views(avd, first.target, ev.max_difficulty)
                                              .query("scan == @first.scan"))),
                object_xy_truth=None if obj_truth is None else list(obj_truth["position"]),
                localization_error_m=None if obj_truth is None else
                float(np.linalg.norm(first.data.obj_xy - np.asarray(obj_truth["position"], float))))
    write_json(ctx.out / out_name("evaluate", "track"), info)
    write_json(ctx.out / out_name("evaluate", "summary"), {
        "experiments": summary, "classes": list(first.classes), "target": first.target, "track": first.track,
        "seeds": {"evaluate": ev.seed, "candidates": ev.candidate_seed},
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "features_meta": {k: v for k, v in meta.items() if k != "viewfuse.output_names"},
        "population": population,
        **({"planning": planning} if planning is not None else {}),
    })
    ctx.extra.update(timings_s={k: round(v, 3) for k, v in timings.items()}, n_cells=len(cells),
                     skipped_targets=len(skipped))
    took = time.perf_counter() - t_start
    pooled = population["pooled"]
    return (f"{population['n_targets']} targets x {population['n_tracks']} tracks x {len(population['settings'])} "
            f"settings, {n_rows} result rows; pooled correct(final) "
            + ", ".join(f"{m}={pooled[m]['correct_final']['value']:.2f}" for m in population["methods"])
            + f" ({took:.1f} s)")
