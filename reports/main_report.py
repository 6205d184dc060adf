"""The main report: reads the evaluate (and models) outputs and renders index.html + PNGs.

It only reads results; nothing is recomputed beyond percentiles for plotting (and the summary
metrics, should ``summary.json`` lack an experiment). Every experiment section appears only when
its outputs exist. Loading never runs code: Parquet, JSON and ``np.load(allow_pickle=False)``.

Follows the paper's §5.5: Fig. 16 (GP models), 17a (biased track), 17b–c (randomized percentile
bands), Tables 1–2 (summary), Figs. 12–13 (σ sensitivity), Fig. 18 (bias maps).
"""
from __future__ import annotations

import json
import logging
import math
import platform
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
from tqdm import tqdm

from loaders.errors import BadInputError
from pipeline.metrics import mgr_percentile_fields
from reports.results_io import read_result_table
from reports.figures import (METHOD_ORDER, class_colors, method_style, new_figure, new_subplots,
                             percentile_bands, save)
from reports.html import HtmlReport, mgr_cell

log = logging.getLogger("viewfuse.report")

RESULT_COLUMNS = ("experiment", "setting", "sigma_m", "bias_x", "bias_y", "realization", "step",
                  "method", "posterior", "p_truth", "log_mgr", "msde", "correct")
SUMMARY_KEYS = ("correct_final", "correct_overall", "mgr75_final", "mgr95_final",
                "mgr75_overall", "mgr95_overall", "n_realizations")
PACKAGES = (("numpy", "numpy"), ("scipy", "scipy"), ("scikit-learn", "sklearn"), ("torch", "torch"),
            ("torchvision", "torchvision"), ("pandas", "pandas"), ("pyarrow", "pyarrow"),
            ("matplotlib", "matplotlib"), ("h5py", "h5py"), ("opencv-python-headless", "cv2"))


# ==============================================================================================
# Loading
# ==============================================================================================
@dataclass
class EvaluateOutputs:
    """What the evaluate stage left, each part None when absent."""
    results: pd.DataFrame | None = None
    meta: dict = field(default_factory=dict)
    track: dict | None = None
    gp: dict[str, np.ndarray] | None = None
    bias_maps: dict[str, np.ndarray] | None = None
    summary: dict | None = None

    @property
    def classes(self) -> list[str]:
        for src in (self.meta.get("classes"), (self.summary or {}).get("classes"),
                    (self.track or {}).get("classes")):
            if src:
                return list(src)
        if self.gp is not None and "classes" in self.gp:
            return [str(c) for c in self.gp["classes"]]
        return []

    @property
    def target(self) -> str:
        return (self.meta.get("target") or (self.summary or {}).get("target")
                or (self.track or {}).get("target") or "")

    def experiment(self, name: str) -> pd.DataFrame | None:
        if self.results is None:
            return None
        d = self.results[self.results["experiment"] == name]
        return d if len(d) else None


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise BadInputError(path, f"not valid JSON: {e}") from None
    except UnicodeDecodeError:
        raise BadInputError(path, "not UTF-8 text") from None


def _read_npz(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except ValueError as e:
        # Object arrays need pickle, which would run code on load: refused.
        raise BadInputError(path, f"cannot read without pickle ({e}); store strings as fixed-width "
                                  "unicode arrays") from None
    except (OSError, EOFError) as e:
        raise BadInputError(path, f"not a readable .npz file ({e})") from None
    missing = [k for k in required if k not in data]
    if missing:
        raise BadInputError(path, f"missing array(s) {', '.join(missing)}")
    return data


def read_results(path: Path) -> tuple[pd.DataFrame, dict]:
    """results.parquet and its viewfuse.* metadata (classes parsed from JSON)."""
    df, meta = read_result_table(path, RESULT_COLUMNS)
    if len(df) and not np.isin(df["method"].unique(), list(METHOD_ORDER)).all():
        unknown = sorted(set(df["method"].unique()) - set(METHOD_ORDER))
        log.warning("%s: unknown method(s) %s are shown in grey", path, unknown)
    return df, meta


def load_evaluate(evaluate_dir: str | Path) -> EvaluateOutputs:
    """Read whatever the evaluate stage wrote; raise if it wrote nothing usable."""
    d = Path(evaluate_dir)
    if not d.is_dir():
        raise BadInputError(d, "evaluate output folder not found; run `viewfuse evaluate` first")
    out = EvaluateOutputs()
    if (d / "results.parquet").is_file():
        out.results, out.meta = read_results(d / "results.parquet")
    if (d / "track.json").is_file():
        out.track = _read_json(d / "track.json")
    if (d / "summary.json").is_file():
        out.summary = _read_json(d / "summary.json")
    if (d / "gp_models.npz").is_file():
        out.gp = _read_npz(d / "gp_models.npz", ("grid", "raster_mean", "raster_std", "ring_theta",
                                                 "ring_mean", "ring_std", "train_theta", "train_y"))
        _check_gp(d / "gp_models.npz", out.gp)
    if (d / "bias_maps.npz").is_file():
        out.bias_maps = _read_npz(d / "bias_maps.npz", ("bias_x", "bias_y", "posterior"))
        _check_bias_maps(d / "bias_maps.npz", out.bias_maps)
    if all(v is None for v in (out.results, out.track, out.gp, out.bias_maps, out.summary)):
        raise BadInputError(d, "no evaluate outputs found (expected results.parquet, track.json, "
                               "gp_models.npz, bias_maps.npz or summary.json)")
    return out


def _check_gp(path: Path, g: dict) -> None:
    rm, G = g["raster_mean"], g["grid"].shape[0]
    if rm.ndim != 4 or rm.shape[2:] != (G, G) or g["raster_std"].shape != rm.shape:
        raise BadInputError(path, f"raster_mean/raster_std must be (C, F, {G}, {G}), got "
                                  f"{rm.shape} and {g['raster_std'].shape}")
    C, F = rm.shape[:2]
    T = g["ring_theta"].shape[0]
    for k in ("ring_mean", "ring_std"):
        if g[k].shape != (C, F, T):
            raise BadInputError(path, f"{k} must be ({C}, {F}, {T}), got {g[k].shape}")
    if g["train_theta"].ndim != 2 or g["train_theta"].shape[0] != C:
        raise BadInputError(path, f"train_theta must be ({C}, N), got {g['train_theta'].shape}")
    N = g["train_theta"].shape[1]
    if g["train_y"].shape != (C, F, N):
        raise BadInputError(path, f"train_y must be ({C}, {F}, {N}), got {g['train_y'].shape}")


def _check_bias_maps(path: Path, b: dict) -> None:
    p = b["posterior"]
    B = (b["bias_y"].shape[0], b["bias_x"].shape[0])
    if p.ndim != 4 or p.shape[2:] != B:
        raise BadInputError(path, f"posterior must be (K, C, {B[0]}, {B[1]}), got {p.shape}")


def load_models_index(models_dir: str | Path) -> dict | None:
    p = Path(models_dir) / "index.json"
    return _read_json(p) if p.is_file() else None


# ==============================================================================================
# Metrics from results (same definitions as summary.json; used only where it lacks an entry)
# ==============================================================================================
def summary_from_results(df: pd.DataFrame) -> dict:
    """{setting: {method: metrics}} for one experiment's rows."""
    out: dict = {}
    for (setting, method), g in df.groupby(["setting", "method"], sort=False):
        fin = g[g["step"] == g["step"].max()]
        out.setdefault(setting, {})[method] = {
            "correct_final": float(fin["correct"].mean()),
            "correct_overall": float(g["correct"].mean()),
            **mgr_percentile_fields(fin["log_mgr"].to_numpy(float), g["log_mgr"].to_numpy(float)),
            "n_realizations": int(g["realization"].nunique()),
        }
    return out


def mgr95_log10(m: dict) -> float:
    """log10 of the final-step 95th-percentile MGR of one summary entry (nan if absent)."""
    if m.get("log10_mgr95_final") is not None:
        return float(m["log10_mgr95_final"])
    r = m.get("mgr95_final")
    return float(np.log10(r)) if r is not None and float(r) > 0 else float("nan")


def experiment_summary(ev: EvaluateOutputs, exp: str) -> dict:
    s = ((ev.summary or {}).get("experiments") or {}).get(exp)
    if s:
        return s
    d = ev.experiment(exp)
    return summary_from_results(d) if d is not None else {}


def _methods(df: pd.DataFrame) -> list[str]:
    present = list(df["method"].unique())
    return [m for m in METHOD_ORDER if m in present] + sorted(m for m in present if m not in METHOD_ORDER)


def _matrix(df: pd.DataFrame, column: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values R × K) of one column for one (setting, method)."""
    piv = df.pivot_table(index="realization", columns="step", values=column, aggfunc="first")
    return piv.columns.to_numpy(), piv.to_numpy(dtype=float)


def _step_ticks(ax, steps) -> None:
    """Every step labelled on short tracks; integer ticks chosen by matplotlib on long ones."""
    from matplotlib.ticker import MaxNLocator
    if len(steps) <= 12:
        ax.set_xticks(steps)
    else:
        ax.xaxis.set_major_locator(MaxNLocator(nbins=10, integer=True))


def _short(name: str, n: int = 22) -> str:
    s = str(name).replace("_", " ")
    return s if len(s) <= n else s[: n - 1] + "…"


# ==============================================================================================
# Figures (each returns a matplotlib Figure)
# ==============================================================================================
def fig_gp_rasters(gp: dict, classes: list[str], comp_names: list[str], test_inputs) -> Any:
    rm = gp["raster_mean"]
    C, F = rm.shape[:2]
    grid = gp["grid"]
    ext = (grid[0], grid[-1], grid[0], grid[-1])
    fig, axes = new_subplots(C, F, w=1.2 + 2.3 * F, h=0.9 + 2.1 * C, sharex=True, sharey=True)
    circle = np.linspace(0, 2 * np.pi, 200)
    for f in range(F):
        # One colour scale per component (column) so classes can be compared directly.
        vals = np.concatenate([rm[:, f].ravel(), gp["train_y"][:, f].ravel()])
        vals = vals[np.isfinite(vals)]
        vmin, vmax = (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)
        for c in range(C):
            ax = axes[c, f]
            ax.grid(False)
            im = ax.imshow(rm[c, f], extent=ext, origin="lower", cmap="viridis", vmin=vmin, vmax=vmax,
                           interpolation="bilinear")
            ax.plot(np.cos(circle), np.sin(circle), color="white", lw=0.8, alpha=0.8)
            th, y = gp["train_theta"][c], gp["train_y"][c, f]
            ok = np.isfinite(th) & np.isfinite(y)
            ax.scatter(np.cos(th[ok]), np.sin(th[ok]), c=y[ok], cmap="viridis", vmin=vmin, vmax=vmax,
                       s=14, edgecolors="white", linewidths=0.5, zorder=3)
            if test_inputs is not None and len(test_inputs):
                u = np.asarray(test_inputs, float)
                ax.scatter(u[:, 0], u[:, 1], marker="x", color="#ff3030", s=22, lw=1.2, zorder=4)
            ax.set_aspect("equal")
            if c == 0:
                ax.set_title(comp_names[f] if f < len(comp_names) else f"component {f}")
            if f == 0:
                ax.set_ylabel(f"{_short(classes[c]) if c < len(classes) else c}\nu_y")
            if c == C - 1:
                ax.set_xlabel("u_x")
        fig.colorbar(im, ax=axes[:, f], orientation="horizontal", shrink=0.85, pad=0.02,
                     label="GP mean score")
    fig.suptitle("GP mean over the unit square (rows: class, columns: score component)\n"
                 "dots: training views on the ring; red ×: track views")
    return fig


def fig_gp_ring(gp: dict, classes: list[str], comp_names: list[str], test_inputs) -> Any:
    C, F = gp["ring_mean"].shape[:2]
    ncol = 2 if F == 4 else min(F, 3)
    nrow = math.ceil(F / ncol)
    fig, axes = new_subplots(nrow, ncol, w=0.6 + 4.0 * ncol, h=0.9 + 2.8 * nrow)
    cols = class_colors(C)
    deg = np.degrees(_as_radians(gp["ring_theta"])) % 360
    order = np.argsort(deg)
    for f in range(nrow * ncol):
        ax = axes.flat[f]
        if f >= F:
            ax.set_visible(False)
            continue
        for c in range(C):
            mu, sd = gp["ring_mean"][c, f][order], gp["ring_std"][c, f][order]
            lab = _short(classes[c], 32) if c < len(classes) else str(c)
            ax.plot(deg[order], mu, color=cols[c], lw=1.6, label=lab)
            ax.fill_between(deg[order], mu - 2 * sd, mu + 2 * sd, color=cols[c], alpha=0.13, lw=0)
            th, y = gp["train_theta"][c], gp["train_y"][c, f]
            ok = np.isfinite(th) & np.isfinite(y)
            ax.scatter(np.degrees(_as_radians(th[ok])) % 360, y[ok], color=cols[c], s=7, alpha=0.55,
                       lw=0)
        if test_inputs is not None and len(test_inputs):
            u = np.asarray(test_inputs, float)
            for a in np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360:
                ax.axvline(a, color="#888888", lw=0.7, ls=":", zorder=0)
        ax.set_xlim(0, 360)
        ax.set_xticks(range(0, 361, 90))
        ax.set_xlabel("viewing angle on the ring (deg)")
        ax.set_ylabel("score")
        ax.set_title(comp_names[f] if f < len(comp_names) else f"component {f}")
    fig.legend(*axes.flat[0].get_legend_handles_labels(), loc="outside lower center",
               ncol=min(C, 4), fontsize=8, frameon=False)
    fig.suptitle("GP mean ± 2σ on the training ring, with training points (dotted: track views)")
    return fig


def _as_radians(theta: np.ndarray) -> np.ndarray:
    # The contract stores angles in radians; tolerate degrees (values far beyond 2π).
    t = np.asarray(theta, float)
    return np.radians(t) if np.nanmax(np.abs(t), initial=0.0) > 2 * np.pi + 0.5 else t


def fig_biased(df: pd.DataFrame, n_classes: int) -> Any:
    fig, ax = new_figure(6.8, 3.8)
    for m in _methods(df):
        st = method_style(m)
        steps, v = _matrix(df[df["method"] == m], "p_truth")
        if v.shape[0] == 1:
            ax.plot(steps, v[0], "-o", color=st["color"], label=st["label"], ms=4, lw=1.8)
        else:  # several realizations: median and 10–90% range
            ax.plot(steps, np.nanmedian(v, 0), "-o", color=st["color"], label=st["label"] + " (median)",
                    ms=4, lw=1.8)
            ax.fill_between(steps, np.nanpercentile(v, 10, 0), np.nanpercentile(v, 90, 0),
                            color=st["color"], alpha=0.15, lw=0)
    if n_classes:
        ax.axhline(1 / n_classes, color="#777777", ls="--", lw=1, label=f"uniform (1/{n_classes})")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("track step k")
    ax.set_ylabel("P(ground-truth class | history)")
    _step_ticks(ax, steps)
    ax.legend(loc="best")
    return fig


def fig_track(track: dict, biases: list[tuple[float, float]]) -> Any:
    fig, ax = new_figure(6.0, 5.2)
    cam = np.asarray(track.get("camera_xy") or [], float).reshape(-1, 2)
    hd = np.asarray(track.get("heading_rad") or [], float)
    ax.plot(cam[:, 0], cam[:, 1], "-", color="#888888", lw=1, zorder=1)
    ax.scatter(cam[:, 0], cam[:, 1], color="#1f3b70", s=28, zorder=3, label="camera (dataset pose)")
    span = float(np.ptp(cam, axis=0).max()) if len(cam) > 1 else 1.0
    L = 0.08 * max(span, 0.5)
    if hd.shape[0] == cam.shape[0]:
        ax.quiver(cam[:, 0], cam[:, 1], np.cos(hd) * L, np.sin(hd) * L, angles="xy", scale_units="xy",
                  scale=1, color="#1f3b70", width=0.004, zorder=3)
    for k, (x, y) in enumerate(cam):
        ax.annotate(str(k), (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    for i, b in enumerate(biases):
        bc = cam + np.asarray(b, float)
        ax.scatter(bc[:, 0], bc[:, 1], facecolors="none", edgecolors="#D55E00", s=28, zorder=2,
                   label=f"biased estimate ({b[0]:+.2f}, {b[1]:+.2f}) m" if i < 3 else None)
        for p, q in zip(cam, bc):
            ax.plot([p[0], q[0]], [p[1], q[1]], color="#D55E00", lw=0.7, alpha=0.6, zorder=1)
    est = track.get("object_xy_est")
    tru = track.get("object_xy_truth")
    if est is not None:
        ax.scatter([est[0]], [est[1]], marker="X", s=90, color="#009E73", zorder=4,
                   label="object (ray-intersection estimate)")
    if tru is not None:
        ax.scatter([tru[0]], [tru[1]], marker="*", s=140, facecolors="none", edgecolors="black",
                   zorder=5, label="object (truth)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, ground frame)")
    ax.set_ylabel("y (m, ground frame)")
    ax.legend(loc="best", fontsize=7.5)
    return fig


def fig_bands(df: pd.DataFrame, column: str, ylabel: str, title: str) -> tuple[Any, int]:
    """One panel per method, shared y; returns (fig, number of non-finite values clipped)."""
    methods = _methods(df)
    fig, axes = new_subplots(1, len(methods), w=0.8 + 3.5 * len(methods), h=3.6, sharey=True)
    clipped = 0
    mats = {m: _matrix(df[df["method"] == m], column) for m in methods}
    finite = np.concatenate([v[np.isfinite(v)] for _, v in mats.values()] + [np.zeros(1)])
    cap = float(finite.max()) if finite.size else 1.0
    for ax, m in zip(axes[0], methods):
        steps, v = mats[m]
        bad = np.isposinf(v)
        clipped += int(bad.sum())
        v = np.where(bad, cap, v)  # +inf (truth probability underflowed) drawn at the top
        st = method_style(m)
        percentile_bands(ax, steps, v, st["color"], label="")
        ax.set_title(f"{st['label']} (R = {v.shape[0]})")
        ax.set_xlabel("track step k")
        _step_ticks(ax, steps)
    axes[0, 0].set_ylabel(ylabel)
    if column == "p_truth":
        axes[0, 0].set_ylim(-0.02, 1.02)
    elif cap > 10.0:
        # Shared axis spanning 0..thousands: symlog keeps the near-zero method readable too.
        axes[0, 0].set_yscale("symlog", linthresh=1.0)
        axes[0, 0].set_ylim(bottom=-0.05)  # log MGR >= 0; no empty negative half
    fig.suptitle(title)
    return fig, clipped


def fig_sensitivity(summ: dict, sigma_of: dict[str, float]) -> Any:
    fig, axes = new_subplots(1, 2, w=10.0, h=3.8)
    methods = [m for m in METHOD_ORDER if any(m in v for v in summ.values())]
    methods += sorted({m for v in summ.values() for m in v} - set(methods))
    settings = sorted(summ, key=lambda s: sigma_of.get(s, math.nan))
    sig = np.array([sigma_of.get(s, math.nan) for s in settings])
    for m in methods:
        st = method_style(m)
        cf = np.array([summ[s].get(m, {}).get("correct_final", np.nan) for s in settings], float)
        co = np.array([summ[s].get(m, {}).get("correct_overall", np.nan) for s in settings], float)
        mg = np.array([mgr95_log10(summ[s].get(m, {})) for s in settings], float)
        axes[0, 0].plot(sig, cf, "-o", color=st["color"], label=f"{st['label']}: final", ms=4)
        axes[0, 0].plot(sig, co, "--", color=st["color"], label=f"{st['label']}: overall", lw=1, alpha=0.8)
        axes[0, 1].plot(sig, mg, "-o", color=st["color"], label=st["label"], ms=4)
    axes[0, 0].set_ylim(-0.02, 1.02)
    axes[0, 0].set_xlabel("localization noise σ (m)")
    axes[0, 0].set_ylabel("correct classification ratio")
    axes[0, 0].set_title("Correct ratio vs σ")
    axes[0, 0].legend(loc="best", fontsize=7.5)
    # log10 MGR on a symlog axis: ours sits near 0-1 while Model Based can reach 10^3000.
    axes[0, 1].set_yscale("symlog", linthresh=1.0)
    axes[0, 1].axhline(0.0, color="#777777", ls="--", lw=1)
    axes[0, 1].set_xlabel("localization noise σ (m)")
    axes[0, 1].set_ylabel("log10 MGR, 95th pct., final step")
    axes[0, 1].set_title("Confident misclassification vs σ (lower is better)")
    axes[0, 1].legend(loc="best", fontsize=7.5)
    return fig


def bias_map_rgb(post: np.ndarray, colors: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(C, By, Bx) posterior -> (By, Bx, 3) image: hue = argmax class, brightness = its probability.

    Brightness runs from 0.25 at a uniform posterior (1/C) to 1 at certainty, so ties look dark.
    """
    from matplotlib.colors import to_rgb
    C = post.shape[0]
    arg = np.argmax(post, axis=0)
    pmax = np.take_along_axis(post, arg[None], axis=0)[0]
    lo = 1.0 / C
    t = np.clip((pmax - lo) / max(1.0 - lo, 1e-12), 0.0, 1.0)
    base = np.array([to_rgb(c) for c in colors])[arg]
    return base * (0.25 + 0.75 * t)[..., None], arg


def fig_bias_maps(bm: dict, classes: list[str], target: str, images: list[str]) -> Any:
    from matplotlib.patches import Patch
    post = bm["posterior"]
    K, C = post.shape[:2]
    nrow = math.ceil(K / 5)
    ncol = math.ceil(K / nrow)  # balanced rows: 6 views -> 2 x 3, 9 -> 2 x 5
    fig, axes = new_subplots(nrow, ncol, w=0.6 + 2.5 * ncol, h=1.3 + 2.5 * nrow, sharex=True, sharey=True)
    cols = class_colors(C)
    bx, by = bm["bias_x"], bm["bias_y"]
    ext = (bx[0], bx[-1], by[0], by[-1])
    ti = classes.index(target) if target in classes else -1
    for k in range(nrow * ncol):
        ax = axes.flat[k]
        if k >= K:
            ax.set_visible(False)
            continue
        ax.grid(False)
        rgb, arg = bias_map_rgb(post[k], cols)
        ax.imshow(rgb, extent=ext, origin="lower", interpolation="nearest")
        if ti >= 0 and (arg == ti).any() and not (arg == ti).all():
            ax.contour(bx, by, (arg == ti).astype(float), levels=[0.5], colors="white", linewidths=1.3)
        ax.plot([0], [0], marker="+", color="white", ms=10, mew=2)
        name = images[k] if k < len(images) else ""
        ax.set_title(f"view {k}" + (f"\n{name}" if name else ""), fontsize=8.5)
        if k % ncol == 0:
            ax.set_ylabel("bias y (m)")
        if k >= (nrow - 1) * ncol or k + ncol >= K:
            ax.set_xlabel("bias x (m)")
    handles = [Patch(color=cols[c], label=_short(classes[c] if c < len(classes) else str(c), 30)
                     + (" (truth)" if c == ti else "")) for c in range(C)]
    from matplotlib.lines import Line2D
    handles.append(Line2D([], [], color="#444444", lw=1.3, label="truth-class region (white outline)"))
    handles.append(Line2D([], [], color="#444444", marker="+", ls="", ms=9, mew=2, label="zero bias"))
    fig.legend(handles=handles, loc="outside upper center", ncol=min(len(handles), 3), fontsize=8,
               frameon=False)
    return fig


# ==============================================================================================
# Tables and text
# ==============================================================================================
def summary_rows(summ: dict, sigma_of: dict[str, float] | None = None) -> list[list]:
    rows = []
    settings = list(summ)
    if sigma_of:
        settings.sort(key=lambda s: sigma_of.get(s, math.nan))
    for s in settings:
        ms = [m for m in METHOD_ORDER if m in summ[s]] + sorted(set(summ[s]) - set(METHOD_ORDER))
        for m in ms:
            v = summ[s][m]
            rows.append([s, method_style(m)["label"]]
                        + [mgr_cell(v.get(k), v.get(f"log10_{k}")) if k.startswith("mgr") else v.get(k)
                           for k in SUMMARY_KEYS])
    return rows


SUMMARY_HEADER = ["setting", "method", "correct ratio, final", "correct ratio, overall",
                  "MGR 75%, final", "MGR 95%, final", "MGR 75%, overall", "MGR 95%, overall",
                  "realizations"]


_HP_NAMES = {"mean": "prior mean m", "amplitude": "amplitude a", "length_scale": "length scale ℓ",
             "noise": "noise σn²", "log_marginal_likelihood": "log marg. lik.", "n_train": "N train",
             "component_name": "component name"}
_HP_PREFERRED = ("mean", "amplitude", "length_scale", "noise", "log_marginal_likelihood", "n_train")
# Bookkeeping of the optimizer, not hyperparameters: left out of the table.
_HP_HIDDEN = {"warnings", "at_bound", "init", "restarts", "random_state"}


def _str_list(v) -> list[str]:
    """A JSON field that holds one string or a list of them, as a list of strings."""
    v = v or []
    return [v] if isinstance(v, str) else [str(x) for x in v]


def hyperparameter_table(index: dict) -> tuple[list[str], list[list], list[str]]:
    """Header, rows and warnings from models/index.json.

    Uses ``fits`` (one diagnostics dict per (class, component), as ``pipeline.gp`` reports them;
    a list or a dict of dicts) and falls back to ``hyperparameters`` ({class: {component:
    {...}}}) when there are no fit diagnostics. ``warnings`` and ``at_bound`` lists become the
    warnings column and the warning lines under the table.
    """
    # stages.models stores pipeline.gp's per-fit diagnostics as "diagnostics"; "fits" also accepted.
    fits = index.get("fits") or index.get("diagnostics") or []
    if isinstance(fits, dict):
        fits = [dict(v, fit=k) if isinstance(v, dict) else {"fit": k, "value": v} for k, v in fits.items()]
    if not fits and isinstance(index.get("hyperparameters"), dict):
        fits = [dict(hp, **{"class": cls, "component": comp})
                for cls, per in index["hyperparameters"].items() if isinstance(per, dict)
                for comp, hp in per.items() if isinstance(hp, dict)]
    fits = [f for f in fits if isinstance(f, dict)]
    # Identity columns; a column that is empty everywhere (e.g. no component names) is dropped.
    id_keys = [k for k in ("fit", "class", "component", "component_name")
               if any(f.get(k) not in (None, "") for f in fits)]
    skip = set(id_keys) | _HP_HIDDEN
    scalar = set()
    for f in fits:
        scalar |= {k for k, v in f.items() if k not in skip and isinstance(v, (int, float, str, bool))}
    cols = [k for k in _HP_PREFERRED if k in scalar] + sorted(scalar - set(_HP_PREFERRED))
    header = [_HP_NAMES.get(k, k) for k in id_keys + cols] + ["warnings"]
    rows, warns = [], []
    for f in fits:
        at_bound, messages = (_str_list(f.get(key)) for key in ("at_bound", "warnings"))
        ident = " / ".join(str(f.get(k)) for k in id_keys if f.get(k) is not None)
        warns += [f"{ident}: {x}" for x in at_bound + messages]
        # The cell stays short (bound flags); the optimizer's full messages are listed below.
        cell = at_bound + ([f"{len(messages)} optimizer message{'s' if len(messages) > 1 else ''} (below)"]
                           if messages else [])
        rows.append([f.get(k) for k in id_keys] + [f.get(k) for k in cols] + ["; ".join(cell)])
    warns += [str(w) for w in (index.get("warnings") or [])]
    return header, rows, warns


def component_labels(index: dict | None, gp: dict | None) -> list[str]:
    """'name (score k)' per chosen component, from the models index or the GP arrays."""
    comps: list = []
    if index and index.get("components") is not None:
        comps = list(index["components"])
    elif gp is not None and "components" in gp:
        comps = [int(c) for c in gp["components"]]
    names = list((index or {}).get("component_names") or [])
    out = []
    for i, k in enumerate(comps):
        n = names[i] if i < len(names) else None
        out.append(f"{n} (score {k})" if n not in (None, "") else f"score {k}")
    return out


def dump_toml(d: dict, prefix: str = "") -> str:
    """TOML-style text of a nested dict (for reading, not for re-parsing)."""
    scal = {k: v for k, v in d.items() if not isinstance(v, dict)}
    subs = {k: v for k, v in d.items() if isinstance(v, dict)}
    lines = []
    if prefix and scal:
        lines.append(f"[{prefix}]")
    for k, v in scal.items():
        lines.append(f"{k} = {json.dumps(v, ensure_ascii=False)}")
    if scal:
        lines.append("")
    for k, v in subs.items():
        lines.append(dump_toml(v, f"{prefix}.{k}" if prefix else k))
    return "\n".join(lines)


def find_seeds(d: Any, prefix: str = "") -> dict[str, Any]:
    """Every key named 'seed' in a nested dict, by dotted path."""
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            p = f"{prefix}.{k}" if prefix else k
            if k == "seed" and not isinstance(v, dict):
                out[p] = v
            else:
                out.update(find_seeds(v, p))
    return out


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist, _mod in PACKAGES:
        try:
            out[dist] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


# ==============================================================================================
# The page
# ==============================================================================================
@dataclass
class ReportResult:
    index: Path
    figures: list[str]
    sections: list[str]
    notes: list[str]


def build_main_report(evaluate_dir: str | Path, models_dir: str | Path | None, out_dir: str | Path, *,
                      title: str = "viewfuse report", dpi: int = 110, run_name: str = "",
                      config: dict | None = None, timings: dict[str, float] | None = None,
                      progress: bool = True) -> ReportResult:
    """Render ``out_dir/index.html`` and its PNGs from existing evaluate (and models) outputs."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ev = load_evaluate(evaluate_dir)
    index = load_models_index(models_dir) if models_dir is not None else None
    classes, target = ev.classes, ev.target
    track = ev.track or {}
    notes: list[str] = []
    sections: list[str] = []

    comp_names = component_labels(index, ev.gp)

    # -- plan the figures, render them with one progress bar -----------------------------------
    plan: list[tuple[str, Callable[[], Any]]] = []
    test_inputs = track.get("gp_inputs")
    if ev.gp is not None:
        plan.append(("gp_rasters.png", lambda: fig_gp_rasters(ev.gp, classes, comp_names, test_inputs)))
        plan.append(("gp_ring.png", lambda: fig_gp_ring(ev.gp, classes, comp_names, test_inputs)))
    biased = ev.experiment("biased")
    biases: list[tuple[float, float]] = []
    if biased is not None:
        biases = sorted({(float(x), float(y)) for x, y in zip(biased["bias_x"], biased["bias_y"])})
        plan.append(("biased_ptruth.png", lambda: fig_biased(biased, len(classes))))
    if track.get("camera_xy"):
        plan.append(("track.png", lambda: fig_track(track, biases)))
    rnd = ev.experiment("randomized")
    rnd_settings = list(dict.fromkeys(rnd["setting"])) if rnd is not None else []
    clipped: dict[str, int] = {}
    for i, s in enumerate(rnd_settings):
        sub = rnd[rnd["setting"] == s]
        sfx = "" if len(rnd_settings) == 1 else f"_{i}"

        def bands(sub=sub, col="p_truth", ttl=f"P(truth) per step, percentiles 10–90% in 10% steps ({s})",
                  yl="P(ground-truth class)", key=f"randomized_ptruth{sfx}.png"):
            fig, n = fig_bands(sub, col, yl, ttl)
            clipped[key] = n
            return fig
        plan.append((f"randomized_ptruth{sfx}.png", bands))
        plan.append((f"randomized_logmgr{sfx}.png",
                     lambda sub=sub, s=s, key=f"randomized_logmgr{sfx}.png": _bands_logmgr(sub, s, key, clipped)))
    sens = ev.experiment("sensitivity")
    sens_sigma: dict[str, float] = {}
    if sens is not None:
        sens_sigma = {s: float(g["sigma_m"].iloc[0]) for s, g in sens.groupby("setting")}
        sens_summ = experiment_summary(ev, "sensitivity")
        plan.append(("sensitivity.png", lambda: fig_sensitivity(sens_summ, sens_sigma)))
    if ev.bias_maps is not None:
        bm_images = [str(x) for x in ev.bias_maps.get("images", track.get("images") or [])]
        bm_classes = [str(c) for c in ev.bias_maps["classes"]] if "classes" in ev.bias_maps else classes
        plan.append(("bias_maps.png", lambda: fig_bias_maps(ev.bias_maps, bm_classes, target, bm_images)))

    written: list[str] = []
    for name, build in tqdm(plan, desc="report figures", unit="fig", disable=not progress):
        save(build(), out / name, dpi)
        written.append(name)

    # -- page ----------------------------------------------------------------------------------
    scan = track.get("scan", "")
    sub = " · ".join(x for x in (f"run {run_name}" if run_name else "", f"target {target}" if target else "",
                                  f"scan {scan}" if scan else "") if x)
    page = HtmlReport(title, sub)

    page.section("Overview", anchor="overview")
    sections.append("overview")
    facts = [["run", run_name or "—"], ["target (ground truth)", target or "—"],
             ["candidate classes", ", ".join(classes) or "—"], ["scan", scan or "—"]]
    if track:
        K = len(track.get("images") or [])
        facts.append(["track", f"{K} views: " + ", ".join(track.get("images") or [])])
        est, tru = track.get("object_xy_est"), track.get("object_xy_truth")
        if est is not None:
            facts.append(["object position estimate (m)", f"({est[0]:.3f}, {est[1]:.3f})"])
        if est is not None and tru is not None:
            err = math.hypot(est[0] - tru[0], est[1] - tru[1])
            facts.append(["object position error", f"{100 * err:.1f} cm (ray intersection vs truth)"])
        elif track.get("localization_error_m") is not None:  # the evaluate stage's own figure
            facts.append(["object position error", f"{100 * float(track['localization_error_m']):.1f} cm"])
        if track.get("yaw_deg") is not None:
            facts.append(["object yaw", f"{float(track['yaw_deg']):.1f}°"])
        if track.get("n_views_seeing_target") is not None:
            facts.append(["views that see the target", str(track["n_views_seeing_target"])])
    if index:
        rule = index.get("rule")
        for key in ("component_choice", "meta"):  # where stages.models records the rule
            if not rule and isinstance(index.get(key), dict):
                rule = index[key].get("rule")
        facts.append(["GP components", (", ".join(comp_names) or "—") + (f" (rule: {rule})" if rule else "")])
    page.table(["", ""], facts, cls="facts")
    page.paragraph(
        "How to read this: a robot looks at one object from K views along a track and fuses the "
        "classifier's scores with per-class, viewpoint-dependent GP models. The camera positions it "
        "uses are wrong by a localization error. 'With Uncertainty' (the paper's method) averages "
        "over sampled poses and over MC-dropout samples of the classifier; 'Model Based' trusts the "
        "single pose estimate and the mean score. P(truth) is the posterior of the correct class "
        "(higher is better). MGR is max-class probability over truth probability: 1 (log 0) when the "
        "truth is the most likely class, large when the fusion is confidently wrong; its 95th "
        "percentile measures confident misclassifications.")
    if ev.results is None:
        notes.append("results.parquet is missing: the experiment sections are left out.")
    for key, n in clipped.items():
        if n:
            notes.append(f"{key}: {n} infinite value(s) (truth probability 0) drawn at the top of "
                         "the axis.")
    for n in notes:
        log.warning("report: %s", n)
        page.paragraph(n, cls="warn")

    if ev.gp is not None:
        page.section("GP class models", anchor="gp")
        sections.append("gp")
        page.paragraph("Each class has one GP per chosen score component, a function of the viewing "
                       "direction (unit-circle input). Dots on the ring are the training views "
                       "(BigBIRD turntable), coloured by their score on the same scale; red crosses "
                       "are the directions of the track's views (estimated poses).")
        page.figure("gp_rasters.png", "GP mean per class × component over the unit square, with the "
                                      "training ring (paper Fig. 16).")
        page.figure("gp_ring.png", "GP mean ± 2σ along the training ring vs viewing angle, one panel "
                                   "per component, classes in colour; dots are training scores.")

    if biased is not None:
        page.section("Biased track", anchor="biased")
        sections.append("biased")
        b = ", ".join(f"({x:+.2f}, {y:+.2f}) m" for x, y in biases)
        sig = ", ".join(f"{v:.2f}" for v in sorted(set(biased["sigma_m"])))
        page.paragraph(f"Every pose estimate along the track is shifted by a fixed bias {b}. Model "
                       f"Based uses the shifted estimates as if exact; With Uncertainty also knows "
                       f"the localization noise σ = {sig} m and averages over sampled poses.")
        page.figure("biased_ptruth.png", "P(ground-truth class) per step along the biased track "
                                         "(paper Fig. 17a). Dashed: uniform prior.")
        page.table(["method", "P(truth), final", "correct, final", "log MGR, final"],
                   _final_rows(biased), caption="Final step of the biased track.")
    if track.get("camera_xy"):
        if biased is None:
            page.section("Track", anchor="track")
            sections.append("track")
        page.figure("track.png", "Track seen from above: camera positions (numbered in track order) "
                                 "with headings, the object estimate and truth, and the biased pose "
                                 "estimates (hollow).")

    if rnd is not None:
        page.section("Randomized localization error", anchor="randomized")
        sections.append("randomized")
        page.paragraph("Each realization draws pose estimates = truth + bias + N(0, σ²I) per view; "
                       "bands show the 10–90% percentiles of the realizations in 10% steps, the "
                       "median darkest (paper Fig. 17b–c).")
        for i, s in enumerate(rnd_settings):
            sfx = "" if len(rnd_settings) == 1 else f"_{i}"
            page.figure(f"randomized_ptruth{sfx}.png", f"P(ground-truth class) per step, {s}.")
            page.figure(f"randomized_logmgr{sfx}.png", f"log MGR per step, {s} (0 = truth most likely; "
                                                       "higher = more confidently wrong).")
        page.table(SUMMARY_HEADER, summary_rows(experiment_summary(ev, "randomized")), cls="summary",
                   caption="Randomized experiment (paper Tables 1–2): correct ratio at the final step "
                           "and over all steps; MGR percentiles as ratios (1 = truth most likely).")

    if sens is not None:
        page.section("Sensitivity to σ", anchor="sensitivity")
        sections.append("sensitivity")
        page.paragraph("The randomized experiment repeated over a sweep of localization noise σ "
                       "(paper Figs. 12–13).")
        page.figure("sensitivity.png", "Left: correct ratio (solid: final step, dashed: all steps). "
                                       "Right: log10 of the 95th-percentile MGR at the final step "
                                       "(symlog axis; 0 = truth most likely).")
        page.table(SUMMARY_HEADER, summary_rows(experiment_summary(ev, "sensitivity"), sens_sigma),
                   cls="summary sensitivity", caption="Sensitivity sweep, per σ and method.")

    if ev.bias_maps is not None:
        page.section("Bias maps", anchor="bias-maps")
        sections.append("bias_maps")
        page.paragraph("For each track view alone, the Model Based class posterior when its pose "
                       "estimate is off by a 2D bias (x, y): the colour is the most probable class, "
                       "its brightness that class's probability (dark = near uniform). Where the "
                       "truth class loses, a small localization error flips the decision "
                       "(paper Fig. 18).")
        page.figure("bias_maps.png", "Single-view Model Based posterior over a grid of pose biases; "
                                     "'+' marks zero bias, white outline the region where the truth "
                                     "class wins.")

    page.section("GP hyperparameters and warnings", anchor="hyperparameters")
    sections.append("hyperparameters")
    if index:
        header, rows, warns = hyperparameter_table(index)
        if rows:
            page.table(header, rows, caption="Fitted GP hyperparameters per (class, component), "
                                             "from models/index.json.")
        for w in warns:
            page.paragraph(w, cls="warn")
        if not warns:
            page.paragraph("No fit warnings.", cls="note")
    else:
        page.paragraph("models/index.json not found; hyperparameters not shown.", cls="note")

    page.section("Run details", anchor="details")
    sections.append("details")
    seeds = dict(find_seeds(config or {}))
    for k, v in ((ev.summary or {}).get("seeds") or {}).items():
        seeds[f"evaluate output: {k}"] = v
    if "seed" in ev.meta:
        m = str(ev.meta["seed"])
        seeds["results.parquet metadata"] = int(m) if m.lstrip("-").isdigit() else m
    if seeds:
        page.table(["seed", "value"], [[k, v] for k, v in seeds.items()], caption="Seeds.")
    t_rows = [[k, v] for k, v in (timings or {}).items()]
    t_rows += [[f"evaluate: {k}", v] for k, v in ((ev.summary or {}).get("timings_s") or {}).items()]
    if t_rows:
        page.table(["stage / part", "seconds"], t_rows, caption="Timings.")
    page.table(["package", "version"], [[k, v] for k, v in package_versions().items()],
               caption="Package versions.")
    if "config_hash" in ev.meta:
        page.paragraph(f"Config hash (results metadata): {ev.meta['config_hash']}", cls="note")
    if config:
        page.preformatted(dump_toml(config), caption="Resolved configuration.")

    missing = [f for f in page.figures if f not in written]
    if missing:  # a figure referenced but never drawn would show as a broken image
        raise RuntimeError(f"report: figures referenced but not written: {missing}")
    page.write(out / "index.html")
    return ReportResult(out / "index.html", written, sections, notes)


def _bands_logmgr(sub: pd.DataFrame, setting: str, key: str, clipped: dict) -> Any:
    fig, n = fig_bands(sub, "log_mgr", "log MGR = log(max_c P(c) / P(truth))",
                       f"log MGR per step, percentiles 10–90% in 10% steps ({setting})")
    clipped[key] = n
    return fig


def _final_rows(df: pd.DataFrame) -> list[list]:
    rows = []
    for m in _methods(df):
        g = df[df["method"] == m]
        fin = g[g["step"] == g["step"].max()]
        rows.append([method_style(m)["label"], float(fin["p_truth"].mean()), float(fin["correct"].mean()),
                     float(fin["log_mgr"].mean())])
    return rows
