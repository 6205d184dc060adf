"""Stage ``evaluate``: the population evaluation (every target x several tracks x the settings),
its statistics and verdict, and the single-track figures for the first target's first track.

I/O at the edges: read the model banks, the AVD features and the scans' geometry; the grid, the
experiments and the statistics are pure functions in ``pipeline.evaluation.population``,
``pipeline.evaluation.experiments`` and ``pipeline.evaluation.popstats``; cells run on ``run.executor``.
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.evaluation import experiments as E
from pipeline.evaluation import population as P
from pipeline.infra.cache import atomic_path, write_json
from pipeline.infra.config import Config
from pipeline.scoring.features import read_features
from pipeline.method.dirichlet import DirichletModels
from pipeline.method.gp import GPClassModels
from pipeline.evaluation.labels import COMPARISONS, DIRICHLET as DIRICHLET_KEY, METHODS, METRICS
from pipeline.infra.outputs import name as out_name
from pipeline.evaluation.popstats import population_block
from pipeline.evaluation.results import cell_metrics, metadata, result_block, write_results
from pipeline.evaluation.track import TrackError, grid_step

log = logging.getLogger("viewfuse.evaluate")

DEFAULT = "default"


def load_banks(models_dir: Path, ablations: tuple[str, ...]) -> tuple[dict, dict]:
    """{variant: model bank} and {variant: models/index.json} for the default and every ablation."""
    index = _read_index(models_dir)
    banks, indexes = {DEFAULT: GPClassModels.load(models_dir)}, {DEFAULT: index}
    for a in ablations:
        sub = index.get("ablations", {}).get(a)
        if sub is None:
            raise ValueError(f"{models_dir / 'index.json'}: no model bank for ablation {a!r} (rerun the models stage)")
        banks[a] = GPClassModels.load(models_dir / sub)
        indexes[a] = _read_index(models_dir / sub)
    return banks, indexes


def _read_index(folder: Path) -> dict:
    """A model bank's index.json, or an error naming the file."""
    path = folder / out_name("models", "index")
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: model index missing (rerun the models stage)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid JSON ({e}); rerun the models stage") from None


def scan_geometry(cfg: Config, scans: list[str], avd: pd.DataFrame, skips) -> tuple[dict, dict]:
    """Per scan: (fx, cx) of the camera and the capture grid's spacing read off the positions.
    The scan is read under the same skip policy as the features stage, so an entry features
    skipped does not stop this stage."""
    from loaders.avd import AVDScan
    from stages.data import data_roots

    _, avd_root = data_roots(cfg)
    intr, steps = {}, {}
    for s in scans:
        K = AVDScan(avd_root, s, skip=skips.log("avd", "AVD entry")).intrinsics()
        intr[s] = (float(K[0, 0]), float(K[0, 2]))
        cams = avd.loc[avd["scan"] == s, ["cam_x", "cam_y"]].to_numpy(float)
        steps[s] = grid_step(cams)
    return intr, steps


def choose_targets(cfg: Config, avd: pd.DataFrame, plan: dict) -> list[str]:
    ev = cfg.evaluate
    seen = sorted(avd.loc[(avd["difficulty"] <= ev.max_difficulty), "instance"].unique())
    if isinstance(ev.targets, str):
        return [t for t in seen if t in plan]
    missing = [t for t in ev.targets if t not in plan]
    if missing:
        raise ValueError(f"evaluate.targets names {missing[0]!r}, for which the models stage planned no "
                         f"candidate set (modelled: {', '.join(sorted(plan))})")
    return list(ev.targets)


def build_cells(cfg: Config, avd: pd.DataFrame, scores: np.ndarray, indexes: dict, truth: dict | None,
                intr: dict, steps: dict, dirichlet: DirichletModels | None = None
                ) -> tuple[list[P.Cell], list[P.TrackInfo], list[dict]]:
    """Every (variant, target, track) cell; targets without a usable track are skipped with a reason.
    With ``dirichlet`` models, every cell also carries the candidates' Dirichlets and the views'
    whole probability vectors (the fourth method)."""
    ev = cfg.evaluate
    plan = indexes[DEFAULT]["candidate_sets"]
    own = indexes[DEFAULT]["own_components"]
    settings = tuple(P.population_settings(ev))
    cells, tracks, skipped = [], [], []
    for target in choose_targets(cfg, avd, plan):
        det = P.target_views(avd, target, ev.max_difficulty)
        try:
            infos = P.plan_tracks(det, target, ev.tracks_per_target, ev.track_length, ev.seed, intr, steps,
                                  tuple(ev.track_images))
        except TrackError as e:
            skipped.append({"target": target, "reason": str(e)})
            log.warning("target %s skipped: %s", target, e)
            continue
        classes = plan[target]["classes"]
        for info in infos:
            yaw = P.yaw_for(target, info.scan, truth, ev.yaw_source, ev.yaw_deg, ev.targets, ev.yaws_deg)
            full = P.track_samples(avd, scores, info, ev.max_difficulty)
            dm = None if dirichlet is None else dirichlet.subset(classes)
            if dm is not None and full.shape[-1] != dm.dim:
                raise ValueError(f"avd.parquet has {full.shape[-1]} scores per crop, the Dirichlet models {dm.dim}")
            for variant, index in indexes.items():
                comps = index["candidate_sets"][target]["components"]
                data = E.TrackData(images=info.images, cam_xy=info.cam_xy, obj_xy=info.obj_xy, yaw=yaw,
                                   dropout=full[:, :, list(comps)], own=full[:, :, [own[c] for c in classes]],
                                   probs=None if dm is None else full)
                cells.append(P.Cell(variant, target, info.track, info.scan, tuple(classes), tuple(comps),
                                    classes.index(target), data, settings, ev.seed, ev.variance_floor,
                                    difficulty=variant == DEFAULT, dirichlet=dm, n_ss=ev.dirichlet.n_ss))
            tracks.append(info)
        log.info("target %s: %d track(s) in %s; candidates %s", target, len(infos),
                 ", ".join(sorted({i.scan for i in infos})), ", ".join(classes))
    if not cells:
        raise TrackError("no target has a usable track: " + "; ".join(f"{s['target']}: {s['reason']}" for s in skipped))
    return cells, tracks, skipped


def cell_table(cells: list[P.Cell], results: list[dict]) -> pd.DataFrame:
    """One row per (variant, target, track, setting, method) with the cell's metrics."""
    rows = []
    for cell, res in zip(cells, results):
        for (experiment, label), posts in res["posts"].items():
            for method, lp in posts.items():
                rows.append({"variant": cell.variant, "target": cell.target, "track": cell.track, "scan": cell.scan,
                             "experiment": experiment, "setting": label, "method": method,
                             **cell_metrics(lp, cell.truth)})
    return pd.DataFrame(rows)


def result_blocks(cells: list[P.Cell], results: list[dict]) -> list[dict]:
    out = []
    for cell, res in zip(cells, results):
        by_label = {(s.experiment, s.label): s for s in cell.settings}
        for key, posts in res["posts"].items():
            s = by_label[key]
            out.append(result_block(posts, cell.truth, variant=cell.variant, experiment=s.experiment, setting=s.label,
                                    sigma_m=float(s.sigma), bias_x=float(s.bias[0]), bias_y=float(s.bias[1]),
                                    scan=cell.scan, target=cell.target, track=cell.track,
                                    candidates=",".join(cell.classes), truth=cell.truth))
    return out


def population_summary(cfg: Config, table: pd.DataFrame, cells: list[P.Cell], results: list[dict],
                       tracks: list[P.TrackInfo], skipped: list[dict]) -> dict:
    ev = cfg.evaluate
    metrics = list(METRICS)
    methods = [m for m in METHODS if m in set(table["method"])]
    settings = P.population_settings(ev)
    default = table[table["variant"] == DEFAULT]
    n_targets = default["target"].nunique()
    n_tracks = len(tracks)
    scope = f"{n_targets} targets x {n_tracks} tracks x {len(settings)} settings"
    block = population_block(default, methods, metrics, COMPARISONS, ev.bootstrap, ev.seed, scope)
    by_setting = {}
    for s in settings:
        sub = default[default["setting"] == s.label]
        b = population_block(sub, methods, metrics, COMPARISONS, ev.bootstrap, ev.seed,
                             f"{n_targets} targets x {n_tracks} tracks, {s.experiment} {s.label}", per_target=False)
        by_setting[s.label] = {k: b[k] for k in ("pooled", "paired", "verdict", "verdict_table")}
    ablations = {}
    for a in ev.ablations:
        sub = table[table["variant"] == a]
        b = population_block(sub, methods, metrics, COMPARISONS, ev.bootstrap, ev.seed, scope, per_target=False)
        key, value = (t.strip() for t in a.split("=", 1))
        ablations[a] = {"override": {key: value}, **{k: b[k] for k in ("pooled", "paired", "verdict", "verdict_table")}}
    difficulty = [{"target": c.target, "track": c.track, "scan": c.scan, "single_view_first": r["difficulty"]}
                  for c, r in zip(cells, results) if r["difficulty"] is not None]
    spread = {}
    for m in methods:
        v = np.array([d["single_view_first"][m] for d in difficulty])
        spread[m] = {"min": float(v.min()), "q25": float(np.percentile(v, 25)), "median": float(np.median(v)),
                     "q75": float(np.percentile(v, 75)), "max": float(v.max()), "mean": float(v.mean())}
    first = {c.target: c for c in cells if c.variant == DEFAULT}
    cell_rows = [{"target": t, "track": int(tr), "experiment": e, "setting": s,
                  "values": {r["method"]: {k: r[k] for k in metrics} for _, r in g.iterrows()}}
                 for (t, tr, e, s), g in default.groupby(["target", "track", "experiment", "setting"], sort=True)]
    return {
        "n_targets": int(n_targets), "n_tracks": int(n_tracks), "tracks_per_target": ev.tracks_per_target,
        "n_cells": int(len(default) // max(len(methods), 1)), "bootstrap": ev.bootstrap, "ci_level": 0.95,
        "realizations": ev.randomized.realizations, "n_loc_samples": ev.randomized.n_loc_samples,
        "methods": methods, "metrics": metrics,
        "settings": [{"experiment": s.experiment, "setting": s.label, "sigma_m": s.sigma, "bias_m": list(s.bias),
                      "realizations": s.realizations, "n_loc_samples": s.n_x} for s in settings],
        "targets": sorted(first), "candidates": {t: list(c.classes) for t, c in sorted(first.items())},
        "components": {t: list(c.components) for t, c in sorted(first.items())},
        "unit": ("a cell is one (target, track, setting); its metric is computed over its realizations. "
                 "Pooled values average tracks' means (over settings) within each target, then targets; "
                 "95 % CIs resample targets, then tracks within targets (per-target CIs: tracks)."),
        **block,
        "by_setting": by_setting,
        "difficulty": {"tracks": difficulty, "summary": spread,
                       "meaning": "share of a track's views whose single-view posterior at the true pose ranks "
                                  "the target first"},
        "cells": cell_rows,
        "tracks": [t.as_dict() for t in tracks],
        "ablations": ablations,
        "skipped_targets": skipped,
    }


def dirichlet_summary(cfg: Config, cells: list[P.Cell], results: list[dict]) -> dict | None:
    """What the Dirichlet's posterior cloud says besides its mean: the spread (std of λ) of the
    truth's probability at the final step over the default cells, and the first cell's per-step
    E[λ] and std."""
    pairs = [(c, r) for c, r in zip(cells, results) if c.variant == DEFAULT and "dirichlet_std" in r]
    if not pairs:
        return None
    final = np.array([r["dirichlet_std"][-1, c.truth] for c, r in pairs])
    c0, r0 = pairs[0]
    mean0 = np.exp(next(iter(r0["posts"].values()))[DIRICHLET_KEY][0])
    return {"n_ss": cfg.evaluate.dirichlet.n_ss, "poses": "ignored: the same posterior for every realization",
            "truth_std_final": {"median": float(np.median(final)), "q25": float(np.percentile(final, 25)),
                                "q75": float(np.percentile(final, 75)), "max": float(final.max()),
                                "n_cells": int(len(final))},
            "first_track": {"target": c0.target, "track": c0.track, "classes": list(c0.classes),
                            "mean": mean0.tolist(), "std": r0["dirichlet_std"].tolist()}}


def single_track(cfg: Config, ctx, banks, first: P.Cell, blocks: list, summary: dict, timings: dict) -> None:
    """The first target's first track: sensitivity sweep, bias maps, GP rasters (paper figures)."""
    ev = cfg.evaluate
    models = banks[DEFAULT].subset(first.classes, first.components)
    if "gp_models" in ev.experiments:
        t0 = time.perf_counter()
        with atomic_path(ctx.out / out_name("evaluate", "gp_models")) as tmp, open(tmp, "wb") as f:
            np.savez(f, **E.gp_rasters(models))
        timings["gp_models"] = time.perf_counter() - t0
    if "sensitivity" in ev.experiments:
        t0 = time.perf_counter()
        dirichlet = P.dirichlet_track(first)
        for s in P.sensitivity_settings(ev):
            posts = E.randomized(models, first.data, s.bias, s.sigma, s.realizations, s.n_x,
                                 P.cell_rng(ev.seed, first.target, first.track, s), var_floor=ev.variance_floor)
            if dirichlet is not None:
                posts = P.with_dirichlet(posts, dirichlet[0])
            blocks.append(result_block(posts, first.truth, variant=DEFAULT, experiment=s.experiment, setting=s.label,
                                       sigma_m=float(s.sigma), bias_x=float(s.bias[0]), bias_y=float(s.bias[1]),
                                       scan=first.scan, target=first.target, track=first.track,
                                       candidates=",".join(first.classes), truth=first.truth))
            summary.setdefault("sensitivity", {})[s.label] = E.summarize(posts, first.truth)
        timings["sensitivity"] = time.perf_counter() - t0
    if "bias_maps" in ev.experiments:
        t0 = time.perf_counter()
        axis, post = E.bias_maps(models, first.data, ev.bias_maps.extent_m, ev.bias_maps.steps)
        with atomic_path(ctx.out / out_name("evaluate", "bias_maps")) as tmp, open(tmp, "wb") as f:
            np.savez(f, bias_x=axis, bias_y=axis, posterior=post, classes=np.array(first.classes),
                     images=np.array(first.data.images))
        timings["bias_maps"] = time.perf_counter() - t0


def run(ctx) -> str:
    from pipeline.infra.executor import executor_for

    cfg: Config = ctx.cfg
    ev = cfg.evaluate
    t_start = time.perf_counter()
    banks, indexes = load_banks(ctx.input("models"), tuple(ev.ablations))
    dirichlet = DirichletModels.load(ctx.input("models") / out_name("models", "dirichlet"))
    avd_path = ctx.input("features") / out_name("features", "avd")
    avd, scores, meta = read_features(avd_path)
    if avd.empty:
        raise TrackError(f"{avd_path} holds no AVD box: nothing to evaluate")
    scans = sorted(avd["scan"].unique())
    intr, steps = scan_geometry(cfg, scans, avd, ctx.skips)
    truth_path = ctx.input("data") / out_name("data", "truth")
    truth = json.loads(truth_path.read_text()) if truth_path.is_file() else None
    cells, tracks, skipped = build_cells(cfg, avd, scores, indexes, truth, intr, steps, dirichlet)

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    executor = executor_for(cfg)
    try:
        results = executor.map(P.run_cell, cells, shared=banks, desc="evaluate: cells", unit="cell")
    finally:
        executor.close()
    timings["population"] = time.perf_counter() - t0
    log.info("population: %d cells (%d targets x %d tracks x %d variant(s)) in %.1f s", len(cells),
             len({c.target for c in cells}), len(tracks), len(indexes), timings["population"])

    t0 = time.perf_counter()
    table = cell_table(cells, results)
    population = population_summary(cfg, table, cells, results, tracks, skipped)
    population["dirichlet"] = dirichlet_summary(cfg, cells, results)
    timings["statistics"] = time.perf_counter() - t0

    # The first target's first track: its biased/randomized tables as before, plus the figures.
    first = cells[0]
    summary: dict = {}
    for (experiment, label), posts in results[0]["posts"].items():
        summary.setdefault(experiment, {})[label] = E.summarize(posts, first.truth)
    blocks = result_blocks(cells, results)
    single_track(cfg, ctx, banks, first, blocks, summary, timings)
    n_rows = write_results(blocks, ctx.out / out_name("evaluate", "results"), metadata(
        config_hash=cfg.section_hash("evaluate"), seed=str(ev.seed), classes=list(first.classes),
        target=first.target))
    info = tracks[0].as_dict()
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
        "experiments": summary, "classes": list(first.classes), "target": first.target,
        "seeds": {"evaluate": ev.seed, "candidates": ev.candidate_seed},
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "features_meta": {k: v for k, v in meta.items() if k != "viewfuse.output_names"},
        "population": population,
    })
    ctx.extra.update(timings_s={k: round(v, 3) for k, v in timings.items()}, n_cells=len(cells),
                     skipped_targets=len(skipped))
    took = time.perf_counter() - t_start
    pooled = population["pooled"]
    return (f"{population['n_targets']} targets x {population['n_tracks']} tracks x {len(population['settings'])} "
            f"settings, {n_rows} result rows; pooled correct(final) "
            + ", ".join(f"{m}={pooled[m]['correct_final']['value']:.2f}" for m in population["methods"])
            + f" ({took:.1f} s)")
