"""Figure helpers shared by the reports: Agg figures, atomic PNG writes, percentile bands, labels.

Method and class colours and names come from ``pipeline.evaluation.labels`` (one place for the project).

Figures are built on ``matplotlib.figure.Figure`` directly (no pyplot), so nothing depends on a
display or on pyplot's global state, and a figure needs no explicit close.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pipeline.infra.cache import atomic_path

DEFAULT_LEVELS = (10, 20, 30, 40, 50, 60, 70, 80, 90)

_RC = {
    # Every text is literal: names from the config and the dataset ("$\\foo$" in
    # simulate.class_names) would otherwise be parsed as mathtext, and a bad one aborts the figure.
    "text.parse_math": False,
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.labelsize": 9.5,
    "legend.fontsize": 8.5,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
}


def wrap_label(name: str, width: int = 18) -> str:
    """A class or target name on as many lines as it needs (underscores read as spaces), never cut."""
    import textwrap
    return "\n".join(textwrap.wrap(str(name).replace("_", " "), width)) or str(name)


def step_ticks(ax, steps) -> None:
    """Every step labelled on short tracks; integer ticks chosen by matplotlib on long ones."""
    from matplotlib.ticker import MaxNLocator
    if len(steps) <= 12:
        ax.set_xticks(list(steps))
    else:
        ax.xaxis.set_major_locator(MaxNLocator(nbins=10, integer=True))


def _apply_rc() -> None:
    import matplotlib
    matplotlib.rcParams.update(_RC)


def new_figure(w: float = 6.4, h: float = 4.0) -> tuple[Figure, "object"]:
    """A figure with one axes, on the Agg canvas."""
    fig, axes = new_subplots(1, 1, w=w, h=h)
    return fig, axes[0, 0]


def new_subplots(nrows: int, ncols: int, w: float = 6.4, h: float = 4.0, *, sharex: bool = False,
                 sharey: bool = False, squeeze: bool = False, height_ratios=None) -> tuple[Figure, np.ndarray]:
    """A figure with a grid of axes (always a 2-D array unless ``squeeze``)."""
    _apply_rc()
    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, sharex=sharex, sharey=sharey, squeeze=squeeze,
                        height_ratios=height_ratios)
    return fig, axes


def save(fig: Figure, path, dpi: int = 110) -> None:
    """Write ``fig`` as PNG atomically (temp name + rename)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: figures are written as .png")
    with atomic_path(path) as tmp:
        # No creation timestamp in the metadata: the same results give the same bytes.
        # bbox "tight" keeps outside legends and edge labels from being clipped.
        fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": None}, bbox_inches="tight",
                    pad_inches=0.06)



def percentile_bands(ax, steps: Sequence[float], values, color: str, label: str = "",
                     levels: Sequence[float] = DEFAULT_LEVELS) -> None:
    """Nested percentile bands of ``values`` (R realizations × K steps) per step.

    Steps are discrete, so bands and median are drawn as steps centred on each step (no
    interpolated triangles between steps).

    ``levels`` are percentiles; they pair symmetrically around the median (10–90, 20–80, …),
    each pair shaded with the same light alpha so overlaps get darker toward the centre; the
    median is drawn as the darkest line. NaNs are ignored per step.
    """
    v = np.asarray(values, dtype=float)
    x = np.asarray(steps, dtype=float)
    if v.ndim != 2 or v.shape[1] != x.shape[0]:
        raise ValueError(f"percentile_bands: values must be (R, K) with K = {x.shape[0]} steps, "
                         f"got shape {v.shape}")
    lv = sorted(float(p) for p in levels)
    if any(not 0 <= p <= 100 for p in lv):
        raise ValueError(f"percentile_bands: levels must lie in [0, 100], got {levels}")
    lows = [p for p in lv if p < 50]
    ok = np.isfinite(v).any(axis=0)
    if not ok.any():
        return
    x, v = x[ok], v[:, ok]
    q = {p: np.nanpercentile(v, p, axis=0) for p in set(lows) | {100 - p for p in lows} | {50.0}}
    n = max(len(lows), 1)
    alpha = min(0.85, 1.6 / (n + 1))  # n stacked bands reach ~0.8 opacity at the centre
    for i, p in enumerate(lows):
        ax.fill_between(x, q[p], q[100 - p], step="mid", color=color, alpha=alpha, linewidth=0,
                        label=(f"{label}: {p:g}–{100 - p:g}%" if label and i == 0 else None))
    ax.plot(x, q[50.0], color=_darken(color, 0.55), linewidth=2.0, drawstyle="steps-mid",
            label=(f"{label}: median" if label else None))


def _darken(color: str, factor: float) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb
    r, g, b = to_rgb(color)
    return (r * factor, g * factor, b * factor)
