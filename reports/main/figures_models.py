"""Figures of the class models and the single-view posteriors: GP rasters, GP ring, bias maps.

Every raster carries a colour scale; class names are wrapped, never cut.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from pipeline.evaluation.metrics.labels import class_colors
from reports.shared.figures import new_subplots, wrap_label
from reports.shared.numbers import percent


def _as_radians(theta: np.ndarray) -> np.ndarray:
    # The contract stores angles in radians; tolerate degrees (values far beyond 2π).
    t = np.asarray(theta, float)
    return np.radians(t) if np.nanmax(np.abs(t), initial=0.0) > 2 * np.pi + 0.5 else t


def _component_limits(gp: dict, f: int) -> tuple[float, float]:
    """One colour scale per component (column), so classes compare directly."""
    vals = np.concatenate([gp["raster_mean"][:, f].ravel(), gp["train_y"][:, f].ravel()])
    vals = vals[np.isfinite(vals)]
    return (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)


def _raster_panel(ax, gp: dict, c: int, f: int, lim: tuple[float, float], test_inputs) -> Any:
    grid = gp["grid"]
    ax.grid(False)
    im = ax.imshow(gp["raster_mean"][c, f], extent=(grid[0], grid[-1], grid[0], grid[-1]), origin="lower",
                   cmap="viridis", vmin=lim[0], vmax=lim[1], interpolation="bilinear")
    circle = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(circle), np.sin(circle), color="white", lw=0.8, alpha=0.8)
    th, y = _as_radians(gp["train_theta"][c]), gp["train_y"][c, f]
    ok = np.isfinite(th) & np.isfinite(y)
    ax.scatter(np.cos(th[ok]), np.sin(th[ok]), c=y[ok], cmap="viridis", vmin=lim[0], vmax=lim[1],
               s=14, edgecolors="white", linewidths=0.5, zorder=3)
    if test_inputs is not None and len(test_inputs):
        u = np.asarray(test_inputs, float)
        ax.scatter(u[:, 0], u[:, 1], marker="x", color="#ff3030", s=22, lw=1.2, zorder=4)
    ax.set_aspect("equal")
    return im


def fig_gp_rasters(gp: dict, classes: list[str], comp_names: list[str], test_inputs) -> Any:
    C, F = gp["raster_mean"].shape[:2]
    fig, axes = new_subplots(C, F, w=1.6 + 2.3 * F, h=1.2 + 2.1 * C, sharex=True, sharey=True)
    for f in range(F):
        lim = _component_limits(gp, f)
        for c in range(C):
            im = _raster_panel(axes[c, f], gp, c, f, lim, test_inputs)
        axes[0, f].set_title(wrap_label(comp_names[f] if f < len(comp_names) else f"component {f}", 22))
        axes[C - 1, f].set_xlabel("u_x")
        fig.colorbar(im, ax=axes[:, f], orientation="horizontal", shrink=0.85, pad=0.02,
                     label="GP mean score")
    for c in range(C):
        axes[c, 0].set_ylabel(f"{wrap_label(classes[c]) if c < len(classes) else c}\nu_y")
    fig.suptitle("GP mean over the unit square (rows: class, columns: score component)\n"
                 "dots: training views on the ring; red ×: track views")
    return fig


def fig_gp_ring(gp: dict, classes: list[str], comp_names: list[str], test_inputs) -> Any:
    C, F = gp["ring_mean"].shape[:2]
    ncol = 2 if F == 4 else min(F, 3)
    nrow = math.ceil(F / ncol)
    fig, axes = new_subplots(nrow, ncol, w=0.6 + 4.0 * ncol, h=1.1 + 2.8 * nrow)
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
            lab = str(classes[c]).replace("_", " ") if c < len(classes) else str(c)
            ax.plot(deg[order], mu, color=cols[c], lw=1.6, label=lab)
            ax.fill_between(deg[order], mu - 2 * sd, mu + 2 * sd, color=cols[c], alpha=0.13, lw=0)
            th, y = gp["train_theta"][c], gp["train_y"][c, f]
            ok = np.isfinite(th) & np.isfinite(y)
            ax.scatter(np.degrees(_as_radians(th[ok])) % 360, y[ok], color=cols[c], s=7, alpha=0.55, lw=0)
            if "obs_theta" in gp and c < len(gp["obs_theta"]):  # the class's AVD crops: test-domain fit
                oth, oy = gp["obs_theta"][c], gp["obs_y"][c, f]
                ok = np.isfinite(oth) & np.isfinite(oy)
                ax.scatter(np.degrees(oth[ok]) % 360, oy[ok], color=cols[c], s=14, marker="x", lw=0.9)
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
               ncol=min(C, 2), fontsize=8, frameon=False)
    fig.suptitle("GP mean ± 2σ on the training ring, with training points (dots),\nAVD crop scores of the "
                 "scan (crosses; dotted: track views)" if "obs_theta" in gp else
                 "GP mean ± 2σ on the training ring, with training points (dotted: track views)")
    return fig


def bias_map_rgb(post: np.ndarray, colors: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(C, By, Bx) posterior -> (By, Bx, 3) image: hue = argmax class, brightness = its probability.

    Brightness runs from 0.45 at a uniform posterior (1/C) to 1 at certainty: near-ties look dark,
    but never so dark that two hues merge. Class identity does not rest on hue alone: the maps also
    carry region boundaries and class letters (``fig_bias_maps``), which survive greyscale.
    """
    from matplotlib.colors import to_rgb
    C = post.shape[0]
    arg = np.argmax(post, axis=0)
    pmax = np.take_along_axis(post, arg[None], axis=0)[0]
    lo = 1.0 / C
    t = np.clip((pmax - lo) / max(1.0 - lo, 1e-12), 0.0, 1.0)
    base = np.array([to_rgb(c) for c in colors])[arg]
    return base * (0.45 + 0.55 * t)[..., None], arg


def class_letter(i: int) -> str:
    return chr(ord("A") + i) if i < 26 else str(i)


def _bias_map_key(ax, classes: list[str], colors: list[str], truth: int) -> None:
    """The colour scale of the bias maps: per class (row, with its letter), brightness vs winning
    probability."""
    C = len(colors)
    # Start just above 1/C: at exactly 1/C every class ties and argmax would pick another hue.
    p = np.linspace(1.0 / C, 1.0, 65)[1:]
    post = np.zeros((C, C, p.size))
    for c in range(C):
        post[:, c, :] = (1 - p) / max(C - 1, 1)
        post[c, c, :] = p
    rgb, _ = bias_map_rgb(post, colors)
    ax.grid(False)
    ax.imshow(rgb, aspect="auto", extent=(p[0], 1.0, C - 0.5, -0.5), interpolation="nearest")
    ax.set_yticks(range(C))
    ax.set_yticklabels([f"{class_letter(i)}  " + str(n).replace("_", " ") + (" (truth)" if i == truth else "")
                        for i, n in enumerate(classes)], fontsize=8.5)
    for i in range(C):
        _letter(ax, p[len(p) // 2], i, class_letter(i))
    ax.set_xlabel("probability of the winning class (colour scale)", fontsize=8.5)
    ax.set_xticks([round(1.0 / C, 2), 0.5, 0.75, 1.0] if C > 2 else [0.5, 0.75, 1.0])


def _letter(ax, x: float, y: float, text: str, size: float = 9.0) -> None:
    import matplotlib.patheffects as pe
    ax.text(x, y, text, ha="center", va="center", fontsize=size, fontweight="bold", color="white",
            path_effects=[pe.withStroke(linewidth=2.2, foreground="black")])


def _label_regions(ax, arg: np.ndarray, bx: np.ndarray, by: np.ndarray) -> None:
    """Each class region's letter at its largest connected piece (pieces under 4 % of the map
    stay unlabelled), and black boundaries between regions."""
    from scipy import ndimage
    for c in np.unique(arg):
        lab, n = ndimage.label(arg == c)
        if n == 0:
            continue
        sizes = ndimage.sum(np.ones_like(lab), lab, index=range(1, n + 1))
        j = int(np.argmax(sizes))
        if sizes[j] < 0.04 * arg.size:
            continue
        ys, xs = np.nonzero(lab == j + 1)
        # the member pixel nearest the piece's centroid (a centroid can fall outside a ring)
        cy, cx = ys.mean(), xs.mean()
        # keep off the zero-bias '+' (the map's centre): move the spot up by a quarter of the map
        oy, ox = int(np.argmin(np.abs(by))), int(np.argmin(np.abs(bx)))
        if abs(cy - oy) < 0.2 * arg.shape[0] and abs(cx - ox) < 0.2 * arg.shape[1]:
            cy += 0.28 * arg.shape[0]
        # and off the map's edges, where a letter would run into the panel's title (the build checks)
        inner = ((np.abs(by[ys] - (by[0] + by[-1]) / 2) <= 0.38 * abs(by[-1] - by[0]))
                 & (np.abs(bx[xs] - (bx[0] + bx[-1]) / 2) <= 0.42 * abs(bx[-1] - bx[0])))
        if inner.any():
            ys, xs = ys[inner], xs[inner]
        i = int(np.argmin((ys - cy) ** 2 + (xs - cx) ** 2))
        # a piece on the edge alone: its letter moves in by the margin (still over the piece's edge row)
        mx, my = (bx[0] + bx[-1]) / 2, (by[0] + by[-1]) / 2
        rx, ry = 0.42 * abs(bx[-1] - bx[0]), 0.38 * abs(by[-1] - by[0])
        _letter(ax, float(np.clip(bx[xs[i]], mx - rx, mx + rx)), float(np.clip(by[ys[i]], my - ry, my + ry)),
                class_letter(int(c)))
    if len(np.unique(arg)) > 1:
        ax.contour(bx, by, arg.astype(float), levels=np.unique(arg)[:-1] + 0.5, colors="black", linewidths=0.7)


def bias_map_findings(bm: dict, classes: list[str], target: str) -> dict:
    """Per view: does the truth class win at zero bias, on what share of the bias grid, and the
    smallest bias (m) at which it loses; plus which class wins most where the truth loses."""
    post = bm["posterior"]
    K, C = post.shape[:2]
    names = [str(c) for c in classes] + [str(i) for i in range(len(classes), C)]
    ti = names.index(target) if target in names else -1
    bx, by = np.asarray(bm["bias_x"], float), np.asarray(bm["bias_y"], float)
    X, Y = np.meshgrid(bx, by)
    r = np.hypot(X, Y)
    i0 = (int(np.argmin(np.abs(by))), int(np.argmin(np.abs(bx))))
    views = []
    for k in range(K):
        arg = np.argmax(post[k], axis=0)
        wins = arg == ti
        lose_r = r[~wins]
        views.append({"view": k, "truth_at_zero": bool(wins[i0]), "truth_share": float(wins.mean()),
                      "flip_radius_m": float(lose_r.min()) if lose_r.size and wins[i0] else None,
                      "winner_at_zero": names[int(arg[i0])]})
    return {"truth": target, "views": views, "n_truth_at_zero": sum(v["truth_at_zero"] for v in views),
            "n_views": K}


def fig_bias_maps(bm: dict, classes: list[str], target: str, images: list[str]) -> Any:
    post = bm["posterior"]
    K, C = post.shape[:2]
    ncol = min(K, 4)
    nrow = math.ceil(K / ncol)
    fig, axes = new_subplots(nrow + 1, ncol, w=0.6 + 2.5 * ncol, h=1.8 + 2.5 * nrow,
                             height_ratios=[1.0] * nrow + [0.16 * C + 0.15])
    cols = class_colors(C)
    names = [str(c) for c in classes] + [str(i) for i in range(len(classes), C)]
    bx, by = bm["bias_x"], bm["bias_y"]
    ti = names.index(target) if target in names else -1
    found = bias_map_findings(bm, classes, target)
    for k in range(nrow * ncol):
        ax = axes.flat[k]
        if k >= K:
            ax.set_visible(False)
            continue
        ax.grid(False)
        rgb, arg = bias_map_rgb(post[k], cols)
        ax.imshow(rgb, extent=(bx[0], bx[-1], by[0], by[-1]), origin="lower", interpolation="nearest")
        _label_regions(ax, arg, np.asarray(bx, float), np.asarray(by, float))
        if ti >= 0 and (arg == ti).any() and not (arg == ti).all():
            ax.contour(bx, by, (arg == ti).astype(float), levels=[0.5], colors="white", linewidths=1.8)
        ax.plot([0], [0], marker="+", color="white", ms=10, mew=2)
        v = found["views"][k]
        share = f"truth wins {percent(v['truth_share'])}"
        ax.set_title(f"view {k}" + (f"\n{images[k]}" if k < len(images) else "") + f"\n{share}", fontsize=8.5)
        ax.set_xlabel("bias x (m)")
        ax.set_ylabel("bias y (m)" if k % ncol == 0 else "")
    gs = axes[nrow, 0].get_gridspec()
    for ax in axes[nrow]:
        ax.remove()
    _bias_map_key(fig.add_subplot(gs[nrow, :]), names, cols, ti)
    # wrapped to the figure's width (a narrow figure of few views clipped one long line)
    import textwrap
    chars = max(40, int(fig.get_figwidth() * 11))
    fig.suptitle("\n".join(textwrap.wrap(
        "Single-view Model Based posterior over pose biases: hue and letter = winning class, brightness = its "
        "probability; black lines: class boundaries; white outline: where the truth class wins; +: zero bias",
        chars)))
    return fig
