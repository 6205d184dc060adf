"""A tiny FAKE run folder in the evaluate → report contract (/work/wt/notes/CONTRACT.md), for the
report tests only: classifier/card.json, models/index.json, evaluate/{results.parquet,
summary.json (with "population"), track.json, gp_models.npz, bias_maps.npz} and manifests.

The numbers are made up (a noisy random walk of the posterior toward the truth class, a little
easier for some targets than others), but the population statistics are computed from those
rows the way the contract defines them (cells = (target, track, setting); bootstrap over tracks
within targets and over targets), so the report is exercised exactly as on real results.
``legacy=True`` writes an older run instead: no population columns or key.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from tests.support.report_population import population, single_track_summary

INSTANCES = ("aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "crystal_hot_sauce",
             "honey_bunches_of_oats_honey_roasted", "mahatma_rice")
CLASSES = INSTANCES[:4]          # the first target's candidates (the detailed track)
TARGET = CLASSES[0]
METHODS = ("with_uncertainty", "model_based", "simple_bayes")
ALL_EXPERIMENTS = ("gp_models", "biased", "randomized", "sensitivity", "bias_maps")
ABLATION = "models.noise_floor=dropout"
FAMILIES = ("stripes", "dots", "chevron", "plaid", "waves", "checker", "zigzag", "rings", "hatch",
            "bricks", "scales", "noise")
SCHEMA = pa.schema([
    ("variant", pa.string()), ("experiment", pa.string()), ("setting", pa.string()),
    ("sigma_m", pa.float64()), ("bias_x", pa.float64()), ("bias_y", pa.float64()), ("scan", pa.string()),
    ("target", pa.string()), ("track", pa.int16()), ("candidates", pa.string()), ("truth", pa.int16()),
    ("realization", pa.int32()), ("step", pa.int16()), ("method", pa.string()),
    ("posterior", pa.list_(pa.float64())), ("p_truth", pa.float64()), ("log10_mgr", pa.float64()),
    ("msde", pa.float64()), ("correct", pa.bool_()),
])
DRIFT = {"with_uncertainty": 0.45, "model_based": 0.5, "simple_bayes": 0.3}
NOISE = {"with_uncertainty": 0.5, "model_based": 1.1, "simple_bayes": 0.8}


def setting_label(sigma: float, bias) -> str:
    return f"sigma={sigma:.2f} m, bias=({bias[0]:+.2f}, {bias[1]:+.2f}) m"


RANDOMIZED = ((0.3, (0.0, 0.0)), (0.3, (-0.3, 0.2)))
BIASED = (0.3, (-0.3, 0.2))
SENSITIVITY = ((0.1, (0.0, 0.0)), (0.3, (0.0, 0.0)), (0.5, (0.0, 0.0)))


def _walk(rng, K, C, drift, noise):
    """Posterior trajectories (K, C) with the truth at index 0: log-odds drift plus noise."""
    steps = rng.normal(0.0, noise, (K, C))
    steps[:, 0] += drift
    logit = np.cumsum(steps, axis=0)
    p = np.exp(logit - logit.max(axis=1, keepdims=True))
    return p / p.sum(axis=1, keepdims=True)


def _rows(rng, key: dict, sigma, bias, R: int, K: int, C: int, ease: float, methods) -> list[dict]:
    rows = []
    for r in range(R):
        for m in methods:
            post = _walk(rng, K, C, DRIFT[m] * ease / (1 + sigma), NOISE[m] * (1 + sigma))
            for k, p in enumerate(post):
                rows.append({**key, "setting": setting_label(sigma, bias), "sigma_m": sigma, "bias_x": bias[0],
                             "bias_y": bias[1], "realization": r, "step": k, "method": m,
                             "posterior": p.tolist(), "p_truth": float(p[0]),
                             "log10_mgr": float(np.log10(p.max() / p[0])),
                             "msde": float(np.mean((p - np.eye(C)[0]) ** 2)), "correct": bool(np.argmax(p) == 0)})
    return rows


def candidates_of(target: str) -> list[str]:
    return [target] + [c for c in INSTANCES if c != target][:3]


def make_rows(rng, *, T: int, tracks: int, K: int, R: int, experiments, methods, ablation: bool) -> list[dict]:
    rows = []
    for ti, target in enumerate(INSTANCES[:T]):
        ease = 1.0 - 0.3 * ti  # later targets are harder
        for n in range(tracks):
            key = {"variant": "default", "scan": "Home_001_1", "target": target, "track": n,
                   "candidates": ",".join(candidates_of(target)), "truth": 0}
            if "biased" in experiments:
                rows += _rows(rng, {**key, "experiment": "biased"}, *BIASED, 1, K, 4, ease, methods)
            if "randomized" in experiments:
                for sigma, bias in RANDOMIZED:
                    rows += _rows(rng, {**key, "experiment": "randomized"}, sigma, bias, R, K, 4, ease, methods)
                if ablation:
                    rows += _rows(rng, {**key, "experiment": "randomized", "variant": ABLATION},
                                  *RANDOMIZED[0], R, K, 4, ease * 0.8, methods)
            if "sensitivity" in experiments and ti == 0 and n == 0:
                for sigma, bias in SENSITIVITY:
                    rows += _rows(rng, {**key, "experiment": "sensitivity"}, sigma, bias, R, K, 4, ease, methods)
    return rows


def write_results(path: Path, rows: list[dict], seed: int, legacy: bool) -> None:
    table = pa.Table.from_pylist(rows, schema=SCHEMA)
    if legacy:  # an older run: one target on one track, no population columns
        table = table.drop(["variant", "target", "track", "candidates"])
    meta = {b"viewfuse.classes": json.dumps(list(CLASSES)).encode(), b"viewfuse.target": TARGET.encode(),
            b"viewfuse.config_hash": b"0" * 64, b"viewfuse.seed": str(seed).encode()}
    pq.write_table(table.replace_schema_metadata(meta), path)


def write_track(ev: Path, K: int) -> dict:
    obj = np.array([1.2, 0.9])
    ang = np.linspace(-2.0, 1.0, K)
    cam = obj + 1.1 * np.c_[np.cos(ang), np.sin(ang)]
    heading = np.arctan2(obj[1] - cam[:, 1], obj[0] - cam[:, 0])
    track = {"scan": "Home_001_1", "target": TARGET, "classes": list(CLASSES),
             "images": [f"00011000{i:02d}0101.jpg" for i in range(K)],
             "camera_xy": cam.round(4).tolist(), "heading_rad": heading.round(4).tolist(),
             "object_xy_est": (obj + [0.02, -0.03]).tolist(), "object_xy_truth": obj.tolist(),
             "yaw_deg": 30.0, "gp_inputs": np.c_[np.cos(ang + np.pi), np.sin(ang + np.pi)].round(4).tolist(),
             "localization_error_m": None}
    (ev / "track.json").write_text(json.dumps(track, indent=1))
    return track


def write_gp(ev: Path, rng, comps, G: int) -> None:
    C, F = len(CLASSES), len(comps)
    grid = np.linspace(-1.5, 1.5, G)
    xx, yy = np.meshgrid(grid, grid)
    th = np.arctan2(yy, xx)
    phase = rng.uniform(0, 2 * np.pi, (C, F))
    raster_mean = np.stack([[np.cos(th + phase[c, f]) * np.exp(-(np.hypot(xx, yy) - 1) ** 2) for f in range(F)]
                            for c in range(C)])
    raster_std = 0.1 + 0.3 * np.abs(np.hypot(xx, yy) - 1)[None, None] * np.ones((C, F, 1, 1))
    ring_theta = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    ring_mean = np.cos(ring_theta[None, None] + phase[..., None])
    ring_std = 0.15 + 0.05 * np.sin(ring_theta)[None, None] * np.ones((C, F, 1))
    N = 24
    train_theta, train_y = np.full((C, N), np.nan), np.full((C, F, N), np.nan)
    for c in range(C):
        n = N - 4 * (c % 2)  # unequal N per class: padded with NaN, as in the contract
        train_theta[c, :n] = np.linspace(0, 2 * np.pi, n, endpoint=False)
        train_y[c, :, :n] = np.cos(train_theta[c, :n][None] + phase[c][:, None]) + rng.normal(0, 0.1, (F, n))
    np.savez(ev / "gp_models.npz", grid=grid, raster_mean=raster_mean, raster_std=raster_std, ring_theta=ring_theta,
             ring_mean=ring_mean, ring_std=ring_std, train_theta=train_theta, train_y=train_y,
             classes=np.array(CLASSES), components=np.asarray(comps, np.int64))


def write_bias_maps(ev: Path, K: int, B: int, images: list[str]) -> None:
    C = len(CLASSES)
    bx = by = np.linspace(-0.6, 0.6, B)
    X, Y = np.meshgrid(bx, by)
    post = np.empty((K, C, B, B))
    for k in range(K):
        lg = np.stack([-(X - 0.3 * np.cos(k + c)) ** 2 * 6 - (Y - 0.3 * np.sin(k + c)) ** 2 * 6 for c in range(C)])
        lg[0] += 0.8
        e = np.exp(lg - lg.max(0))
        post[k] = e / e.sum(0)
    np.savez(ev / "bias_maps.npz", bias_x=bx, bias_y=by, posterior=post, classes=np.array(CLASSES),
             images=np.array(images))


def write_models(md: Path, rng, T: int, comps: list[int]) -> dict:
    classes = sorted({c for t in INSTANCES[:T] for c in candidates_of(t)})
    fits = []
    for ci, c in enumerate(classes):
        for i, k in enumerate(comps):
            at = ["noise at lower bound"] if (ci + i) % 3 == 0 else []
            if c == CLASSES[2] and i == 0:
                at.append("length_scale at upper bound")
            fits.append({"class": c, "component": int(k), "component_name": FAMILIES[k], "n_train": 24,
                         "mean": float(rng.normal()), "train_std": float(rng.uniform(0.05, 0.4)),
                         "amplitude": float(rng.uniform(0.1, 2)), "length_scale": float(rng.uniform(0.2, 2)),
                         "noise": 1e-6 if at and at[0].startswith("noise") else float(rng.uniform(1e-4, 0.05)),
                         "log_marginal_likelihood": float(rng.normal(40, 5)),
                         "init": {"amplitude": 1.0, "length_scale": 1.0, "noise": 0.01},
                         "restarts": 5, "random_state": 123, "at_bound": at, "warnings": []})
    index = {"format": "viewfuse-gp-models", "classes": classes, "components": comps,
             "component_names": [FAMILIES[k] for k in comps],
             "candidate_sets": {t: {"classes": candidates_of(t), "components": comps,
                                    "component_names": [FAMILIES[k] for k in comps]} for t in INSTANCES[:T]},
             "component_choice": {"rule": "top_mean", "components": comps},
             "diagnostics": fits, "fits_with_warnings": sum(1 for f in fits if f["at_bound"])}
    (md / "index.json").write_text(json.dumps(index, indent=1))
    return index


def write_classifier(run_dir: Path) -> dict:
    card = {"architecture": "alexnet", "weights": "synthetic", "weights_file": "weights.npz", "num_classes": 12,
            "output_names": list(FAMILIES), "accuracy": 0.94, "val_images": 1200, "hash": "c" * 16,
            "training": {"seed": 3}}
    (run_dir / "classifier").mkdir(parents=True, exist_ok=True)
    (run_dir / "classifier" / "card.json").write_text(json.dumps(card, indent=1))
    return card


def write_manifests(run_dir: Path) -> None:
    extra = {"data": {}, "classifier": {"accuracy": 0.94},
             "features": {"skipped": {"bigbird": {"skipped": 2, "reasons": {"mask is empty": 2},
                                                  "examples": ["NP1_3.jpg: mask is empty"]}, "avd": None}},
             "models": {}, "evaluate": {}}
    for stage, e in extra.items():
        (run_dir / stage).mkdir(parents=True, exist_ok=True)
        m = {"stage": stage, "key": "k" * 8, "parts": {"config": {"source": "synthetic"}} if stage == "data" else {},
             "seconds": 1.5, "summary": "", "extra": e}
        (run_dir / stage / "manifest.json").write_text(json.dumps(m))


def write_fake_run(run_dir: Path, *, T: int = 3, tracks: int = 2, K: int = 5, F: int = 2, G: int = 15, R: int = 6,
                   B: int = 7, seed: int = 0, experiments=ALL_EXPERIMENTS, methods=METHODS, ablation: bool = True,
                   legacy: bool = False, n_boot: int = 200) -> dict:
    """Write ``run_dir/{classifier,models,evaluate,...}`` in the contract format; return facts."""
    rng = np.random.default_rng(seed)
    run_dir = Path(run_dir)
    ev, md = run_dir / "evaluate", run_dir / "models"
    ev.mkdir(parents=True, exist_ok=True)
    md.mkdir(parents=True, exist_ok=True)
    track = write_track(ev, K)
    rows = make_rows(rng, T=1 if legacy else T, tracks=1 if legacy else tracks, K=K, R=R,
                     experiments=experiments, methods=methods, ablation=ablation and not legacy)
    df = pd.DataFrame(rows)
    if rows:
        write_results(ev / "results.parquet", rows, seed, legacy)
    summary = {"experiments": single_track_summary(df, TARGET) if rows else {}, "classes": list(CLASSES),
               "target": TARGET, "seeds": {"evaluate": seed, "localization": seed + 1},
               "timings_s": {e: round(0.1 * (i + 1), 2) for i, e in enumerate(experiments)}}
    if not legacy and rows and "randomized" in experiments:
        summary["population"] = population(df, INSTANCES[:T], candidates_of, FAMILIES, n_boot=n_boot, seed=seed,
                                           ablation=ABLATION if ablation else None, skipped=INSTANCES[4])
    (ev / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    comps = [2, 7, 4, 9][:F]
    if "gp_models" in experiments:
        write_gp(ev, rng, comps, G)
    if "bias_maps" in experiments:
        write_bias_maps(ev, K, B, track["images"])
    index = write_models(md, rng, 1 if legacy else T, comps)
    card = write_classifier(run_dir)
    write_manifests(run_dir)
    return {"K": K, "C": len(CLASSES), "F": F, "R": R, "B": B, "T": T, "tracks": tracks, "rows": df,
            "summary": summary, "track": track, "index": index, "card": card, "run": run_dir,
            "evaluate": ev, "models": md}


@pytest.fixture(scope="session")
def rendered_run(tmp_path_factory):
    """One fake population run and its rendered report, shared by the report and browser tests."""
    from reports.main.page import build_main_report
    root = tmp_path_factory.mktemp("report")
    facts = write_fake_run(root / "run", K=4, R=5)
    res = build_main_report(facts["run"], root / "out", run_name="fake", dpi=50, progress=False, n_boot=300,
                            config={"data": {"source": "synthetic"}, "evaluate": {"seed": 7},
                                    "report": {"dpi": 50}},
                            timings={"models": 1.5, "evaluate": 12.0})
    return facts, res


@pytest.fixture(scope="session")
def rendered_run_default_dpi(tmp_path_factory):
    """A fake run rendered at the report's default dpi (110), as a reader sees it: the legibility
    checks (text size, tick overlaps, the browser at 1400 px) need the real pixel sizes."""
    from reports.main.page import build_main_report
    root = tmp_path_factory.mktemp("report110")
    facts = write_fake_run(root / "run", K=4, R=4, n_boot=50)
    res = build_main_report(facts["run"], root / "out", run_name="fake", progress=False, n_boot=50)
    return facts, res


def only_figures(monkeypatch, *names: str) -> None:
    """Within the test, the main report draws only the figures ``names`` (the others are left out
    as a run without their data leaves them out): a test about one figure, or about a
    contradiction in the tables, need not wait for the other dozen to be laid out."""
    from reports.main import page

    real = page.progress_bar
    monkeypatch.setattr(page, "progress_bar", lambda plan, **kw: real([(n, b) for n, b in plan if n in names], **kw))
