"""Do the class models predict the test domain? Standardized residuals of AVD crops.

For every AVD crop of a modelled instance whose pose is known (the synthetic sidecar's position and
yaw, or the located object and the configured yaw), the mean of its MC-dropout scores is compared,
per score component, with the GP predictive of its own class at the true viewing direction:
``z = (mean score - μ) / sqrt(v)``. ``v`` is the GP predictive variance (σ_n² included: what Model
Based uses), or that plus the view's dropout variance (what With Uncertainty adds), or that plus a
test-domain variance δ² (the calibrated likelihood). A model that describes the domain gives
z ~ N(0, 1): 4.6 % beyond 2, 0.27 % beyond 3, 95 % inside ±1.96, a flat PIT histogram.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
import pandas as pd
from scipy.special import ndtr

from pipeline.method.geometry import relative_inputs
from pipeline.method.score_space import of_models, to_space

Z95 = 1.959963984540054
PIT_BINS = 10
# clr reads each pass's whole score vector: in blocks of this many rows, so that its float64 logs of a
# 1000-way output never hold every labelled pass at once (real_full: 124,400 passes, 1 GB a copy);
# clr is row-wise, so the blocks give the same numbers
CLR_BLOCK = 8192


def crop_residuals(avd: pd.DataFrame, scores: np.ndarray, models, poses: Mapping[tuple[str, str], tuple],
                   max_difficulty: int, var_floor: float) -> pd.DataFrame:
    """One row per (crop, component) of every modelled instance with a pose in ``poses``.

    ``poses`` maps (scan, instance) -> (object xy (2,), yaw rad). Columns: scan, instance, image,
    component (score index), obs (mean dropout score, in the bank's score space), v_z (dropout variance, ddof 0, floored at
    ``var_floor``), mu and var (the own-class GP predictive, σ_n² included), x0, x1 (the GP input:
    the viewing direction on the unit circle, object frame).
    """
    rows = avd[(avd["pass"] >= 0) & (avd["difficulty"] <= max_difficulty) & avd["instance"].isin(models.classes)]
    rows = rows[[(s, i) in poses for s, i in zip(rows["scan"], rows["instance"])]]
    cols = ["scan", "instance", "image", "component", "obs", "v_z", "mu", "var", "x0", "x1"]
    if rows.empty:
        return pd.DataFrame({c: [] for c in cols})
    comps = list(models.components)
    key = rows["scan"].astype(str) + "\x00" + rows["instance"].astype(str) + "\x00" + rows["image"].astype(str)
    code, uniq = pd.factorize(key, sort=True)
    # the used rows and components only, then float64: the whole table in float64 is twice its size
    # in the bank's score space (pipeline/method/score_space.py), each dropout pass before the mean
    sp, floor = of_models(models)
    at, whole = rows.index.to_numpy(), sp == "clr"    # clr reads the whole score vector
    if whole:
        s = np.concatenate([to_space(np.asarray(scores)[at[i:i + CLR_BLOCK]], sp, floor)[:, comps]
                            for i in range(0, len(at), CLR_BLOCK)])
    else:
        s = to_space(np.asarray(scores)[np.ix_(at, comps)], sp, floor)
    n = np.bincount(code).astype(float)
    G, F = len(uniq), len(comps)
    s1, s2 = np.zeros((G, F)), np.zeros((G, F))
    np.add.at(s1, code, s)
    np.add.at(s2, code, s * s)
    obs = s1 / n[:, None]
    v_z = np.maximum(s2 / n[:, None] - obs * obs, var_floor)
    first = rows.groupby(code, sort=True).first()
    out: dict[str, list] = {c: [] for c in cols}   # the columns' pieces, one DataFrame at the end
    for (scan, inst), g in first.groupby(["scan", "instance"], sort=True):
        obj, yaw = poses[(scan, inst)]
        x = relative_inputs(g[["cam_x", "cam_y"]].to_numpy(float), np.asarray(obj, float), float(yaw), unit_circle=True)
        mu, var = models.select([inst]).marginal(x)                      # (n, 1, F)
        idx = g.index.to_numpy()
        n, image = len(idx), g["image"].to_numpy(object)
        # component-major within the (scan, instance): every crop for the first component, then the next
        for f, comp in enumerate(comps):
            for name, v in (("scan", np.full(n, scan, object)), ("instance", np.full(n, inst, object)),
                            ("image", image), ("component", np.full(n, comp, np.int64)), ("obs", obs[idx, f]),
                            ("v_z", v_z[idx, f]), ("mu", mu[:, 0, f]), ("var", var[:, 0, f]), ("x0", x[:, 0]),
                            ("x1", x[:, 1])):
                out[name].append(v)
    return pd.DataFrame({c: np.concatenate(out[c]) for c in cols})


def fit_summary(z: np.ndarray, pit_bins: int = PIT_BINS) -> dict:
    """n, share of |z| > 2 and > 3, coverage of the central 95 % interval, |z| quantiles and the PIT
    histogram (share per equal-width bin of Φ(z); flat at 1 / pit_bins when z ~ N(0, 1))."""
    z = np.asarray(z, float).ravel()
    z = z[np.isfinite(z)]
    if not len(z):
        return {"n": 0, "share_gt2": None, "share_gt3": None, "coverage95": None, "abs_z_p50": None,
                "abs_z_p90": None, "abs_z_p99": None, "pit": None}
    a = np.abs(z)
    hist = np.histogram(ndtr(z), bins=pit_bins, range=(0.0, 1.0))[0] / len(z)
    q50, q90, q99 = np.percentile(a, [50, 90, 99])
    return {"n": int(len(z)), "share_gt2": float(np.mean(a > 2)), "share_gt3": float(np.mean(a > 3)),
            "coverage95": float(np.mean(a <= Z95)), "abs_z_p50": float(q50), "abs_z_p90": float(q90),
            "abs_z_p99": float(q99), "pit": [float(h) for h in hist]}


def standardized(table: pd.DataFrame, kind: str, delta: np.ndarray | None = None) -> np.ndarray:
    """z of every row under ``kind``: 'gp' (var), 'gp_plus_dropout' (var + v_z) or 'gp_calibrated'
    (var + ``delta``, one δ² per row)."""
    r = table["obs"].to_numpy(float) - table["mu"].to_numpy(float)
    v = table["var"].to_numpy(float)
    if kind == "gp_plus_dropout":
        v = v + table["v_z"].to_numpy(float)
    elif kind == "gp_calibrated":
        if delta is None:
            raise ValueError("standardized: 'gp_calibrated' needs the rows' test-domain variances")
        v = v + np.asarray(delta, float)
    elif kind != "gp":
        raise ValueError(f"standardized: unknown kind {kind!r}")
    return r / np.sqrt(v)


def summarize(table: pd.DataFrame, z_by_kind: Mapping[str, np.ndarray]) -> dict:
    """{kind: {"overall": summary, "per_class": {class: {component: summary}}}} for every kind."""
    out = {}
    rows: dict = {}   # class -> component -> its rows (ascending, as a mask over the table gives them)
    for (c, f), idx in table.groupby(["instance", "component"], sort=False).indices.items():
        rows.setdefault(c, {})[f] = idx
    for kind, z in z_by_kind.items():
        per = {str(c): {str(f): fit_summary(z[rows[c][f]]) for f in sorted(rows[c])} for c in sorted(rows)}
        out[kind] = {"overall": fit_summary(z), "per_class": per}
    return out
