"""The population statistics of the fake run (tests/support/report_fixtures.py), computed from its rows
the way the contract defines them. A small, independent implementation: the report only reads
these numbers, it never recomputes them."""
from __future__ import annotations

import numpy as np
import pandas as pd

METRICS = {"correct_final": True, "correct_overall": True, "prob_truth_final": True, "msde_final": False,
           "log10_mgr75_final": False, "log10_mgr95_final": False, "log10_mgr75_overall": False,
           "log10_mgr95_overall": False}
METHODS = ("with_uncertainty", "model_based", "simple_bayes")
COMPARISONS = (("with_uncertainty", "model_based"), ("with_uncertainty", "simple_bayes"))
LABEL = {"with_uncertainty": "With Uncertainty", "model_based": "Model Based", "simple_bayes": "Simple Bayes"}


def cell_metrics(g: pd.DataFrame) -> dict[str, float]:
    """One (…, method) group's metrics over its realizations × steps; MGR as log10."""
    fin = g[g["step"] == g["step"].max()]
    return {"correct_final": float(fin["correct"].mean()), "correct_overall": float(g["correct"].mean()),
            "prob_truth_final": float(fin["p_truth"].mean()), "msde_final": float(fin["msde"].mean()),
            "log10_mgr75_final": float(np.percentile(fin["log10_mgr"], 75)),
            "log10_mgr95_final": float(np.percentile(fin["log10_mgr"], 95)),
            "log10_mgr75_overall": float(np.percentile(g["log10_mgr"], 75)),
            "log10_mgr95_overall": float(np.percentile(g["log10_mgr"], 95))}


def single_track_summary(df: pd.DataFrame, target: str) -> dict:
    """summary.json's "experiments": the first target's first track, default variant."""
    d = df[(df["variant"] == "default") & (df["target"] == target) & (df["track"] == 0)]
    out: dict = {}
    for (exp, setting, method), g in d.groupby(["experiment", "setting", "method"], sort=False):
        out.setdefault(exp, {}).setdefault(setting, {})[method] = {
            **cell_metrics(g), "n_realizations": int(g["realization"].nunique())}
    return out


def _boot(values: dict[str, list[float]], n_boot: int, rng, pooled: bool) -> dict:
    """Mean over cells with a bootstrap CI: tracks within targets, and targets too when pooled
    (every target has the same number of cells here)."""
    v = np.array([values[t] for t in values], float)          # (T, cells per target)
    T, n = v.shape
    tidx = rng.integers(0, T, (n_boot, T)) if pooled else np.broadcast_to(np.arange(T), (n_boot, T))
    kidx = rng.integers(0, n, (n_boot, T, n))
    means = v[tidx[..., None], kidx].mean(axis=(1, 2))
    return {"value": float(v.mean()), "ci_low": float(np.percentile(means, 2.5)),
            "ci_high": float(np.percentile(means, 97.5))}


def _cells(df: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (t, n, s, m), g in df.groupby(["target", "track", "setting", "method"], sort=False):
        rows.append({"target": t, "track": n, "setting": s, "method": m, **cell_metrics(g)})
    return pd.DataFrame(rows)


def _by_target(cells: pd.DataFrame, col) -> dict[str, list[float]]:
    return {t: list(g[col]) if isinstance(col, str) else list(col(g)) for t, g in cells.groupby("target", sort=False)}


def _stats(df: pd.DataFrame, n_boot: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    cells = _cells(df)
    wide = cells.pivot_table(index=["target", "track", "setting"], columns="method", values=list(METRICS)).reset_index()
    out = {"pooled": {}, "per_target": {}, "paired": {}, "paired_per_target": {}, "n_cells": len(wide)}
    for m in METHODS:
        for k in METRICS:
            vals = {t: list(g[(k, m)]) for t, g in wide.groupby("target", sort=False)}
            out["pooled"].setdefault(m, {})[k] = _boot(vals, n_boot, rng, True)
            for t, v in vals.items():
                out["per_target"].setdefault(t, {}).setdefault(m, {})[k] = _boot({t: v}, n_boot, rng, False)
    for a, b in COMPARISONS:
        key = f"{a}-{b}"
        for k, higher in METRICS.items():
            diff = {t: list(g[(k, a)] - g[(k, b)]) for t, g in wide.groupby("target", sort=False)}
            d = np.concatenate([np.asarray(v) for v in diff.values()])
            better = d > 0 if higher else d < 0
            worse = d < 0 if higher else d > 0
            out["paired"].setdefault(key, {})[k] = {**_boot(diff, n_boot, rng, True), "wins": float(better.mean()),
                                                    "losses": float(worse.mean()), "n_cells": int(d.size),
                                                    "better": "higher" if higher else "lower"}
            for t, v in diff.items():
                out["paired_per_target"].setdefault(key, {}).setdefault(t, {})[k] = _boot({t: v}, n_boot, rng, False)
    out["cells"] = wide
    return out


PRIMARY = ("correct_final",)


def records(paired: dict, n_targets: int, n_tracks: int, wide: pd.DataFrame) -> list[dict]:
    """One verdict record per (comparison, metric), in the contract's order and schema
    (pipeline/evaluation/statistics/records.py); every metric here pools by the mean."""
    out = []
    for a, b in COMPARISONS:
        key = f"{a}-{b}"
        for k, higher in METRICS.items():
            d = paired[key][k]
            if d["ci_low"] > 0 or d["ci_high"] < 0:
                outcome = "better" if (d["ci_low"] > 0) == higher else "worse"
            else:
                outcome = "not distinguishable"
            both = wide[[(k, a), (k, b)]].to_numpy()
            ceiling = int((both == 1).all(axis=1).sum()) if k.startswith("correct") else 0
            floor = int((both == 0).all(axis=1).sum()) if k.startswith("correct") else 0
            out.append({"comparison": key, "method": a, "baseline": b, "metric": k, "pooling": "mean",
                        "value": d["value"], "lo": d["ci_low"], "hi": d["ci_high"], "unbounded": False,
                        "over": ["targets", "tracks"],
                        "n": {"targets": n_targets, "tracks": n_tracks, "cells": d["n_cells"]},
                        "better": "higher" if higher else "lower", "outcome": outcome, "primary": k in PRIMARY,
                        "wins": d["wins"], "losses": d["losses"], "unit": "cells",
                        "ceiling_cells": ceiling, "floor_cells": floor})
    return out


def population(df: pd.DataFrame, targets, candidates_of, families, *, n_boot: int, seed: int,
               ablation: str | None, skipped: str) -> dict:
    rnd = df[(df["experiment"] == "randomized") & (df["variant"] == "default")]
    T, n = len(targets), int(rnd["track"].nunique())
    st = _stats(rnd, n_boot, seed)
    recs = records(st["paired"], T, T * n, st["cells"])
    settings = list(dict.fromkeys(rnd["setting"]))
    by_setting = {}
    for s in settings:
        ss = _stats(rnd[rnd["setting"] == s], n_boot, seed)
        by_setting[s] = {"pooled": ss["pooled"], "paired": ss["paired"],
                         "records": records(ss["paired"], T, T * n, ss["cells"])}
    rng = np.random.default_rng(seed + 1)
    tracks = [{"target": t, "track": k, "scan": f"Home_00{1 + k % 2}_1",
               "single_view_first": {m: float(rng.uniform(0.2, 1.0)) for m in METHODS}}
              for t in targets for k in range(n)]
    diff_summary = {m: {q: float(f(np.array([x["single_view_first"][m] for x in tracks])))
                        for q, f in (("min", np.min), ("q25", lambda v: np.percentile(v, 25)), ("median", np.median),
                                     ("q75", lambda v: np.percentile(v, 75)), ("max", np.max), ("mean", np.mean))}
                    for m in METHODS}
    abl = {}
    if ablation:
        ad = df[(df["experiment"] == "randomized") & (df["variant"] == ablation)]
        sa = _stats(ad, n_boot, seed)
        abl[ablation] = {"override": {ablation.split("=")[0]: ablation.split("=")[1]}, "pooled": sa["pooled"],
                         "paired": sa["paired"], "records": records(sa["paired"], T, T * n, sa["cells"])}
    cells = [{"target": r["target"].iloc[0] if hasattr(r["target"], "iloc") else r["target"],
              "track": int(r["track"].iloc[0] if hasattr(r["track"], "iloc") else r["track"]),
              "experiment": "randomized", "setting": str(r["setting"].iloc[0] if hasattr(r["setting"], "iloc") else r["setting"]),
              "values": {m: {k: float(r[(k, m)]) for k in METRICS} for m in METHODS}}
             for _, r in st["cells"].iterrows()]
    return {
        "n_targets": T, "n_tracks": T * n, "tracks_per_target": n, "n_cells": st["n_cells"], "bootstrap": n_boot,
        "ci_level": 0.95, "realizations": int(rnd["realization"].nunique()), "n_loc_samples": 20,
        "methods": list(METHODS), "metrics": list(METRICS),
        "settings": [{"experiment": "randomized", "setting": s, "sigma_m": float(g["sigma_m"].iloc[0]),
                      "bias_m": [float(g["bias_x"].iloc[0]), float(g["bias_y"].iloc[0])]}
                     for s, g in rnd.groupby("setting", sort=False)],
        "targets": list(targets), "candidates": {t: candidates_of(t) for t in targets},
        "components": {t: [f"{families[k]} (score {k})" for k in (2, 7)] for t in targets},
        "unit": "a cell is one (target, track, setting); its metric is computed over its realizations. Pooled "
                "values average the cells within each target, then targets; 95 % CIs resample targets, then "
                "tracks within targets (per-target CIs: tracks).",
        "pooled": st["pooled"], "per_target": st["per_target"], "paired": st["paired"],
        "paired_per_target": st["paired_per_target"], "by_setting": by_setting, "records": recs,
        "primary_metrics": list(PRIMARY), "confident_threshold": 0.99, "ece_bins": 15, "difficulty": {"tracks": tracks, "summary": diff_summary}, "cells": cells,
        "tracks": [{"target": t["target"], "track": t["track"], "scan": t["scan"]} for t in tracks],
        "ablations": abl, "skipped_targets": [{"target": skipped, "reason": "no track of 5 views sees it (3 views)"}],
    }
