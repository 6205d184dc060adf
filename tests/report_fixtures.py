"""Tiny FAKE evaluate/models outputs in the contract format, for the report tests only.

The numbers are made up (a noisy random walk of the posterior toward the truth class), but the
files, columns, dtypes, metadata and array shapes follow the evaluate → report contract, so the
report is exercised exactly as it will be on real results.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

CLASSES = ("aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "crystal_hot_sauce",
           "honey_bunches_of_oats_honey_roasted")
TARGET = CLASSES[0]
ALL_EXPERIMENTS = ("gp_models", "biased", "randomized", "sensitivity", "bias_maps")

SCHEMA = pa.schema([
    ("experiment", pa.string()), ("setting", pa.string()), ("sigma_m", pa.float64()),
    ("bias_x", pa.float64()), ("bias_y", pa.float64()), ("realization", pa.int32()),
    ("step", pa.int16()), ("method", pa.string()), ("posterior", pa.list_(pa.float64())),
    ("p_truth", pa.float64()), ("log_mgr", pa.float64()), ("msde", pa.float64()),
    ("correct", pa.bool_()),
])


def _walk(rng, K, C, truth, drift, noise):
    """A posterior trajectory (K, C): log-odds drift toward the truth plus noise."""
    logit = np.zeros(C)
    out = np.empty((K, C))
    for k in range(K):
        step = rng.normal(0.0, noise, C)
        step[truth] += drift
        logit = logit + step
        p = np.exp(logit - logit.max())
        out[k] = p / p.sum()
    return out


def _rows(exp, setting, sigma, bias, realization, method, post, truth):
    rows = []
    onehot = np.eye(post.shape[1])[truth]
    for k, p in enumerate(post):
        rows.append({
            "experiment": exp, "setting": setting, "sigma_m": float(sigma),
            "bias_x": float(bias[0]), "bias_y": float(bias[1]), "realization": realization,
            "step": k, "method": method, "posterior": [float(v) for v in p],
            "p_truth": float(p[truth]), "log_mgr": float(np.log(p.max() / p[truth])),
            "msde": float(np.mean((p - onehot) ** 2)), "correct": bool(np.argmax(p) == truth),
        })
    return rows


def summarize(rows: list[dict]) -> dict:
    """summary.json's "experiments" block from result rows (same definitions as the contract)."""
    out: dict = {}
    keys = sorted({(r["experiment"], r["setting"], r["method"]) for r in rows})
    for exp, setting, method in keys:
        sel = [r for r in rows if (r["experiment"], r["setting"], r["method"]) == (exp, setting, method)]
        last = max(r["step"] for r in sel)
        fin = [r for r in sel if r["step"] == last]
        lm_all = np.array([r["log_mgr"] for r in sel])
        lm_fin = np.array([r["log_mgr"] for r in fin])
        out.setdefault(exp, {}).setdefault(setting, {})[method] = {
            "correct_final": float(np.mean([r["correct"] for r in fin])),
            "correct_overall": float(np.mean([r["correct"] for r in sel])),
            "mgr75_final": float(np.exp(np.percentile(lm_fin, 75))),
            "mgr95_final": float(np.exp(np.percentile(lm_fin, 95))),
            "mgr75_overall": float(np.exp(np.percentile(lm_all, 75))),
            "mgr95_overall": float(np.exp(np.percentile(lm_all, 95))),
            "n_realizations": len({r["realization"] for r in sel}),
        }
    return out


def write_fake_run(run_dir: Path, *, K: int = 6, F: int = 2, G: int = 15, R: int = 12,
                   B: int = 9, seed: int = 0, experiments=ALL_EXPERIMENTS,
                   methods=("with_uncertainty", "model_based", "simple_bayes")) -> dict:
    """Write ``run_dir/evaluate`` and ``run_dir/models`` in the contract format; return facts."""
    rng = np.random.default_rng(seed)
    run_dir = Path(run_dir)
    ev = run_dir / "evaluate"
    md = run_dir / "models"
    ev.mkdir(parents=True, exist_ok=True)
    md.mkdir(parents=True, exist_ok=True)
    C = len(CLASSES)
    truth = 0

    # -- track: K views on an arc around an object at (1.2, 0.9) --------------------------
    obj = np.array([1.2, 0.9])
    ang = np.linspace(-2.0, 1.0, K)
    cam = obj + 1.1 * np.c_[np.cos(ang), np.sin(ang)]
    heading = np.arctan2(obj[1] - cam[:, 1], obj[0] - cam[:, 0])
    track = {
        "scan": "Home_001_1", "target": TARGET, "classes": list(CLASSES),
        "images": [f"00011000{i:02d}0101.jpg" for i in range(K)],
        "camera_xy": cam.round(4).tolist(), "heading_rad": heading.round(4).tolist(),
        "object_xy_est": (obj + [0.02, -0.03]).tolist(), "object_xy_truth": obj.tolist(),
        "yaw_deg": 30.0, "gp_inputs": np.c_[np.cos(ang + np.pi), np.sin(ang + np.pi)].round(4).tolist(),
        "localization_error_m": None,
    }
    (ev / "track.json").write_text(json.dumps(track, indent=1))

    # -- results --------------------------------------------------------------------------
    rows: list[dict] = []
    drift = {"with_uncertainty": 0.45, "model_based": 0.5, "simple_bayes": 0.3}
    noise = {"with_uncertainty": 0.5, "model_based": 1.1, "simple_bayes": 0.8}
    if "biased" in experiments:
        for m in methods:
            rows += _rows("biased", "bias=(-0.30, +0.20) m", 0.3, (-0.3, 0.2), 0, m,
                          _walk(rng, K, C, truth, drift[m], noise[m]), truth)
    if "randomized" in experiments:
        for r in range(R):
            for m in methods:
                rows += _rows("randomized", "sigma=0.30 m", 0.3, (0.0, 0.0), r, m,
                              _walk(rng, K, C, truth, drift[m], noise[m]), truth)
    if "sensitivity" in experiments:
        for s in (0.1, 0.3, 0.5):
            for r in range(R):
                for m in methods:
                    rows += _rows("sensitivity", f"sigma={s:.2f} m", s, (0.0, 0.0), r, m,
                                  _walk(rng, K, C, truth, drift[m] / (1 + s), noise[m] * (1 + s)), truth)
    if rows:
        table = pa.Table.from_pylist(rows, schema=SCHEMA)
        meta = {b"viewfuse.classes": json.dumps(list(CLASSES)).encode(),
                b"viewfuse.target": TARGET.encode(), b"viewfuse.config_hash": b"0" * 64,
                b"viewfuse.seed": str(seed).encode()}
        pq.write_table(table.replace_schema_metadata(meta), ev / "results.parquet")
    summary = {"experiments": summarize(rows), "classes": list(CLASSES), "target": TARGET,
               "seeds": {"evaluate": seed, "localization": seed + 1},
               "timings_s": {e: round(0.1 * (i + 1), 2) for i, e in enumerate(experiments)}}
    (ev / "summary.json").write_text(json.dumps(summary, indent=1))

    # -- GP models --------------------------------------------------------------------------
    comps = np.array([3, 7][:F] + list(range(10, 10 + max(0, F - 2))), dtype=np.int64)
    if "gp_models" in experiments:
        grid = np.linspace(-1.5, 1.5, G)
        xx, yy = np.meshgrid(grid, grid)
        th = np.arctan2(yy, xx)
        phase = rng.uniform(0, 2 * np.pi, (C, F))
        raster_mean = np.stack([[np.cos(th + phase[c, f]) * np.exp(-(np.hypot(xx, yy) - 1) ** 2)
                                 for f in range(F)] for c in range(C)])
        raster_std = 0.1 + 0.3 * np.abs(np.hypot(xx, yy) - 1)[None, None] * np.ones((C, F, 1, 1))
        T = 72
        ring_theta = np.linspace(0, 2 * np.pi, T, endpoint=False)
        ring_mean = np.cos(ring_theta[None, None] + phase[..., None])
        ring_std = 0.15 + 0.05 * np.sin(ring_theta)[None, None] * np.ones((C, F, 1))
        N = 24
        train_theta = np.full((C, N), np.nan)
        train_y = np.full((C, F, N), np.nan)
        for c in range(C):
            n = N - 4 * (c % 2)  # unequal N per class: padded with NaN, as in the contract
            train_theta[c, :n] = np.linspace(0, 2 * np.pi, n, endpoint=False)
            train_y[c, :, :n] = np.cos(train_theta[c, :n][None] + phase[c][:, None]) + rng.normal(0, 0.1, (F, n))
        np.savez(ev / "gp_models.npz", grid=grid, raster_mean=raster_mean, raster_std=raster_std,
                 ring_theta=ring_theta, ring_mean=ring_mean, ring_std=ring_std,
                 train_theta=train_theta, train_y=train_y, classes=np.array(CLASSES), components=comps)
    if "bias_maps" in experiments:
        bx = np.linspace(-0.6, 0.6, B)
        by = np.linspace(-0.6, 0.6, B)
        X, Y = np.meshgrid(bx, by)
        post = np.empty((K, C, B, B))
        for k in range(K):
            lg = np.stack([-(X - 0.3 * np.cos(k + c)) ** 2 * 6 - (Y - 0.3 * np.sin(k + c)) ** 2 * 6
                           for c in range(C)])
            lg[truth] += 0.8
            e = np.exp(lg - lg.max(0))
            post[k] = e / e.sum(0)
        np.savez(ev / "bias_maps.npz", bias_x=bx, bias_y=by, posterior=post,
                 classes=np.array(CLASSES), images=np.array(track["images"]))

    fits = []
    for c in CLASSES:
        for i, k in enumerate(comps):
            w = ["length_scale at upper bound 10"] if (c == CLASSES[2] and i == 0) else []
            # The diagnostics pipeline.gp.fit_class_models reports per fit.
            fits.append({"class": c, "component": int(k), "component_name": None, "n_train": 24,
                         "mean": float(rng.normal()), "amplitude": float(rng.uniform(0.1, 2)),
                         "length_scale": float(rng.uniform(0.2, 2)), "noise": float(rng.uniform(1e-4, 0.05)),
                         "log_marginal_likelihood": float(rng.normal(40, 5)),
                         "init": {"amplitude": 1.0, "length_scale": 1.0, "noise": 0.01},
                         "restarts": 5, "random_state": 123, "at_bound": w, "warnings": []})
    hyper = {f["class"]: {} for f in fits}
    for f in fits:
        hyper[f["class"]][str(f["component"])] = {k: f[k] for k in ("mean", "amplitude", "length_scale", "noise")}
    index = {"format": "viewfuse-gp-models", "classes": list(CLASSES), "components": comps.tolist(),
             "component_names": None, "hyperparameters": hyper,
             "component_choice": {"rule": "top_mean", "components": comps.tolist()},
             "diagnostics": fits, "fits_with_warnings": 1}
    (md / "index.json").write_text(json.dumps(index, indent=1))
    return {"K": K, "C": C, "F": F, "R": R, "B": B, "rows": rows, "summary": summary,
            "track": track, "index": index, "evaluate": ev, "models": md}
