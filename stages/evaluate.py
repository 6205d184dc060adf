"""Stage ``evaluate``: build the AVD track, locate the object, run the experiments (DESIGN §6).

I/O at the edges: read the models, the AVD features and the scan's geometry; the experiments
themselves are pure functions in ``pipeline.experiments``.
"""
from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from pipeline import experiments as E
from pipeline.cache import atomic_path, write_json
from pipeline.config import Config
from pipeline.features import read_features
from pipeline.gp import GPClassModels
from pipeline.track import TrackError, bearing_rays, facing_error, intersect_rays, select_track

log = logging.getLogger("viewfuse.evaluate")


def object_yaw(cfg: Config, truth: dict | None, target: str) -> float:
    """Object yaw (rad): from the synthetic ground-truth sidecar or from the config."""
    ev = cfg.evaluate
    if ev.yaw_source == "config":
        return math.radians(ev.yaw_deg)
    if truth is None:
        raise FileNotFoundError("evaluate.yaw_source = 'truth' needs the data stage's truth.json "
                                "(synthetic data only); for real data set yaw_source = 'config' and yaw_deg")
    try:
        return math.radians(float(truth["instances"][target]["yaw_deg"]))
    except KeyError:
        raise ValueError(f"truth.json has no yaw for the target {target!r}") from None


def build_track(cfg: Config, avd: pd.DataFrame, scores: np.ndarray, components: list[int],
                intrinsics: np.ndarray, grid_step: float, yaw: float) -> tuple[E.TrackData, dict]:
    """Choose the track views and gather their dropout samples (K, N_s, F)."""
    ev = cfg.evaluate
    tgt = avd[(avd["instance"] == ev.target) & (avd["difficulty"] <= ev.max_difficulty)]
    det = tgt[tgt["pass"] == -1].drop_duplicates("image").set_index("image")
    if len(det) < 2:
        raise TrackError(f"the AVD features hold {len(det)} view(s) of the target {ev.target!r} up to "
                         f"difficulty {ev.max_difficulty}; at least 2 are needed "
                         "(raise evaluate.max_difficulty / features.max_difficulty?)")
    fx, cx = float(intrinsics[0, 0]), float(intrinsics[0, 2])
    cam = det[["cam_x", "cam_y"]].to_numpy(float)
    heading = det["heading"].to_numpy(float)
    box_cx = 0.5 * (det["box_x0"].to_numpy(float) + det["box_x1"].to_numpy(float))
    # Locate the object from every view that sees it (more rays, smaller error).
    obj = intersect_rays(*bearing_rays(cam, heading, box_cx, fx, cx))
    if ev.track_images:
        missing = [n for n in ev.track_images if n not in det.index]
        if missing:
            raise TrackError(f"evaluate.track_images names {missing[0]!r}, which has no scored box of "
                             f"{ev.target!r} up to difficulty {ev.max_difficulty}")
        names = list(ev.track_images)
    else:
        err = facing_error(cam, heading, obj)
        choice = select_track(cam, obj, err, ev.track_length, grid_step=grid_step)
        names = list(det.index[choice.index])
    # Dropout samples of the chosen components, per view, in pass order.
    samples = []
    for name in names:
        rows = tgt[(tgt["image"] == name) & (tgt["pass"] >= 0)].sort_values("pass")
        if rows.empty:
            raise TrackError(f"view {name} has no MC-dropout samples in avd.parquet")
        samples.append(scores[rows.index.to_numpy()][:, components])
    n_s = {len(s) for s in samples}
    if len(n_s) != 1:
        raise TrackError(f"track views have different numbers of dropout samples: {sorted(n_s)}")
    sel = det.loc[names]
    track = E.TrackData(images=tuple(names), cam_xy=sel[["cam_x", "cam_y"]].to_numpy(float),
                        obj_xy=obj, yaw=yaw, dropout=np.stack(samples).astype(np.float64))
    info = {"images": names, "camera_xy": track.cam_xy.tolist(), "heading_rad": sel["heading"].tolist(),
            "object_xy_est": obj.tolist(), "yaw_deg": math.degrees(yaw),
            "gp_inputs": track.inputs(track.cam_xy).tolist(), "n_views_seeing_target": int(len(det))}
    return track, info


def run(ctx) -> str:
    cfg: Config = ctx.cfg
    ev = cfg.evaluate
    t_start = time.perf_counter()
    models = GPClassModels.load(ctx.input("models"))
    if ev.target not in models.classes:
        raise ValueError(f"target {ev.target!r} has no GP model in {ctx.input('models')} "
                         f"(classes: {', '.join(models.classes)})")
    truth_idx = models.classes.index(ev.target)
    avd, scores, meta = read_features(ctx.input("features") / "avd.parquet")
    avd = avd[avd["scan"] == cfg.data.scans[0]]  # one track in one scan (the first of data.scans)

    from loaders.avd import AVDScan
    from stages.data import data_roots
    _, avd_root = data_roots(cfg)
    scan = AVDScan(avd_root, cfg.data.scans[0])
    truth_path = ctx.input("data") / "truth.json"
    truth = json.loads(truth_path.read_text()) if truth_path.is_file() else None
    yaw = object_yaw(cfg, truth, ev.target)
    grid_step = cfg.data.synthetic.grid_step_m if cfg.data.source == "synthetic" else 0.3
    track, info = build_track(cfg, avd, scores, list(models.components), scan.intrinsics(), grid_step, yaw)
    obj_truth = None
    if truth is not None and ev.target in truth.get("instances", {}):
        obj_truth = np.asarray(truth["instances"][ev.target]["position"], float)
    info.update(scan=cfg.data.scans[0], target=ev.target, classes=list(models.classes),
                object_xy_truth=None if obj_truth is None else obj_truth.tolist(),
                localization_error_m=None if obj_truth is None else float(np.linalg.norm(track.obj_xy - obj_truth)))
    write_json(ctx.out / "track.json", info)
    log.info("track: %d views, object at (%.3f, %.3f) m%s", track.k, *track.obj_xy,
             "" if obj_truth is None else f", {info['localization_error_m'] * 100:.1f} cm from the truth")

    # One generator per experiment, derived from the evaluate seed: adding or removing one
    # experiment does not change the others' draws.
    seeds = {name: [ev.seed, i] for i, name in enumerate(("biased", "randomized", "sensitivity"))}
    rng = {name: np.random.default_rng(s) for name, s in seeds.items()}
    frames, summary, timings = [], {}, {}

    if "gp_models" in ev.experiments:
        t0 = time.perf_counter()
        arrays = E.gp_rasters(models)
        with atomic_path(ctx.out / "gp_models.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
        timings["gp_models"] = time.perf_counter() - t0

    if "biased" in ev.experiments:
        t0 = time.perf_counter()
        b = ev.biased
        posts = E.biased(models, track, b.bias_m, b.sigma_m, b.n_loc_samples, rng["biased"],
                         var_floor=ev.variance_floor)
        setting = f"bias=({b.bias_m[0]:+.2f}, {b.bias_m[1]:+.2f}) m, sigma={b.sigma_m:.2f} m"
        frames.append(E.long_rows("biased", setting, b.sigma_m, b.bias_m, posts, truth_idx))
        summary.setdefault("biased", {})[setting] = E.summarize(posts, truth_idx)
        timings["biased"] = time.perf_counter() - t0

    def randomized_block(name: str, sigma: float, bias, realizations: int, n_x: int, gen):
        setting = f"sigma={sigma:.2f} m"
        with tqdm(total=realizations, desc=f"{name} {setting}", unit="real", leave=False) as bar:
            posts = E.randomized(models, track, bias, sigma, realizations, n_x, gen,
                                 var_floor=ev.variance_floor, progress=bar.update)
        frames.append(E.long_rows(name, setting, sigma, bias, posts, truth_idx))
        summary.setdefault(name, {})[setting] = E.summarize(posts, truth_idx)

    if "randomized" in ev.experiments:
        t0 = time.perf_counter()
        r = ev.randomized
        randomized_block("randomized", r.sigma_m, r.bias_m, r.realizations, r.n_loc_samples, rng["randomized"])
        timings["randomized"] = time.perf_counter() - t0

    if "sensitivity" in ev.experiments:
        t0 = time.perf_counter()
        s = ev.sensitivity
        for sigma in s.sigmas_m:
            randomized_block("sensitivity", sigma, ev.randomized.bias_m, s.realizations, s.n_loc_samples,
                             rng["sensitivity"])
        timings["sensitivity"] = time.perf_counter() - t0

    if "bias_maps" in ev.experiments:
        t0 = time.perf_counter()
        axis, post = E.bias_maps(models, track, ev.bias_maps.extent_m, ev.bias_maps.steps)
        with atomic_path(ctx.out / "bias_maps.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, bias_x=axis, bias_y=axis, posterior=post, classes=np.array(models.classes),
                         images=np.array(track.images))
        timings["bias_maps"] = time.perf_counter() - t0

    n_rows = 0
    if frames:
        df = pd.concat(frames, ignore_index=True)
        n_rows = len(df)
        C = len(models.classes)
        table = pa.Table.from_pandas(df, preserve_index=False)
        post_col = pa.array(df["posterior"].map(lambda v: np.asarray(v, np.float64)).tolist(),
                            type=pa.list_(pa.float64(), C))
        table = table.set_column(table.schema.get_field_index("posterior"), "posterior", post_col)
        table = table.replace_schema_metadata({
            "viewfuse.classes": json.dumps(list(models.classes)),
            "viewfuse.target": ev.target,
            "viewfuse.config_hash": cfg.section_hash("evaluate"),
            "viewfuse.seed": str(ev.seed),
        })
        with atomic_path(ctx.out / "results.parquet") as tmp:
            pq.write_table(table, tmp)
    write_json(ctx.out / "summary.json", {
        "experiments": summary, "classes": list(models.classes), "target": ev.target,
        "seeds": {"evaluate": ev.seed, **{k: v for k, v in seeds.items()}},
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "features_meta": {k: v for k, v in meta.items() if k != "viewfuse.output_names"},
    })
    ctx.extra["timings_s"] = timings
    took = time.perf_counter() - t_start
    parts = [f"{track.k}-view track", f"{n_rows} result rows"]
    if "randomized" in summary:
        s = next(iter(summary["randomized"].values()))
        parts.append("randomized correct(final) " + ", ".join(
            f"{m}={v['correct_final']:.2f}" for m, v in s.items()))
    return "; ".join(parts) + f" ({took:.1f} s of experiments)"
