"""Figure helpers shared by the reports: Agg figures, atomic PNG writes, percentile bands, labels.

Method and class colours and names come from ``pipeline.evaluation.metrics.labels`` (one place for the project).

Figures are built on ``matplotlib.figure.Figure`` directly (no pyplot), so nothing depends on a
display or on pyplot's global state, and a figure needs no explicit close.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pipeline.infra.cache import atomic_path
from reports.shared.numbers import plain
from reports.shared.checks import text_artists
from reports.shared.checks import figure_text_problems

DEFAULT_LEVELS = (10, 20, 30, 40, 50, 60, 70, 80, 90)
MAX_WIDTH_IN = 10.8      # widest figure (at 110 dpi: 1188 px + margins; the page's content is 1276 px at 1400 px)
MIN_FONT_PT = 8.0
# log10 MGR axes are symmetric-log: linear within ±MGR_LINTHRESH, logarithmic beyond, so targets
# near 0 and the ones at 1e5 show on one axis (the captions say so).
MGR_LINTHRESH = 1.0
MGR_SCALE_NOTE = "symlog axis: linear in [−1, 1], logarithmic beyond"
# log10 MGR above this is numerical saturation, not a size: the truth's probability fell below 1e-300
# of the winner's (double precision's smallest normal number is ~1e-308), so the value says how far
# the log-probabilities ran apart, not how likely anything is. The pages flag such values.
MGR_SATURATION = 300.0


def mgr_scale_label(head: str) -> str:
    """An axis label for a symlog log10 MGR axis: the quantity, then the scale note on two short
    lines (one long line ran past the canvas on narrow panels)."""
    return f"{head}\n(symlog axis: linear in [−1, 1],\nlogarithmic beyond)"

# Smallest text: 8 pt = 12.2 px at the default 110 dpi, so every label stays >= 11 px at 100 %
# (the report page shows figures at their own size up to MAX_WIDTH_IN; tests check both).
_RC = {
    # Every text is literal: names from the config and the dataset ("$\\foo$" in
    # simulate.class_names) would otherwise be parsed as mathtext, and a bad one aborts the figure.
    "text.parse_math": False,
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.labelsize": 9.5,
    "legend.fontsize": 8.5,
    "xtick.labelsize": 8.5,
    "ytick.labelsize": 8.5,
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
    # Never wider than the page shows at 100 % (a wider PNG is scaled down and its text shrinks
    # below legibility); more panels share the width instead.
    fig = Figure(figsize=(min(w, MAX_WIDTH_IN), h), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, sharex=sharex, sharey=sharey, squeeze=squeeze,
                        height_ratios=height_ratios)
    return fig, axes


@dataclass(frozen=True)
class FigureCheck:
    """What the page and the tests need to know about a written figure."""
    min_font_px: float            # smallest text at 100 % zoom
    overlaps: tuple[str, ...]     # tick labels that overlap a neighbour ('axes title: a / b')
    width_px: int
    text_problems: tuple[str, ...] = ()   # the self-check's: text that overlaps or leaves the canvas


def text_sizes_px(fig: Figure, dpi: float) -> list[float]:
    """Font sizes (px at ``dpi``) of every visible, non-empty text in the figure."""
    from matplotlib.text import Text
    return [t.get_fontsize() * dpi / 72.0 for t in fig.findobj(Text)
            if t.get_visible() and t.get_text().strip() and t.get_figure() is not None]


def freeze_layout(fig: Figure, relayout: bool = False) -> None:
    """Keep the layout the text was checked in: every later draw (the PNG, the checks) places the
    axes where the last layout put them instead of solving the layout again. The layout is
    relative to the canvas, so the PNG's other dpi gives the same places; and the layout solve is
    most of a draw's cost, paid once instead of four times per figure. ``relayout``: the figure
    may have changed since its last draw (``finish_figure`` ran out of rounds, or did not run), so
    lay it out once more first."""
    if relayout:
        fig.draw_without_rendering()
    # None, not "none": savefig lays a figure out once more under any engine, a placeholder too
    fig.set_layout_engine(None)
    if fig.get_layout_engine() is not None:      # rcParams ask for a layout by default
        fig.set_layout_engine("none")


def tick_overlaps(fig: Figure, arts=None, boxes=None) -> list[str]:
    """Pairs of tick labels on one axis whose drawn boxes overlap (after layout). ``arts``: the
    checker's ``text_artists(fig)`` if just made (its tick groups are the labels matplotlib draws);
    ``boxes``: their (group, text, axes, box) if measured since (``layout.last_boxes``)."""
    if boxes is None:
        arts = text_artists(fig) if arts is None else arts
        renderer = fig.canvas.get_renderer()
        boxes = [(g, t, ax, t.get_window_extent(renderer)) for g, t, ax in arts if g]
    groups: dict[str, tuple] = {}
    for g, t, ax, b in boxes:
        if g:
            groups.setdefault(g, (ax, []))[1].append((t.get_text(), b))
    out = []
    for g, (ax, boxes) in groups.items():
        name = g[-1]
        boxes.sort(key=lambda sb: sb[1].x0 if name == "x" else sb[1].y0)
        for (s1, b1), (s2, b2) in zip(boxes, boxes[1:]):
            if b1.overlaps(b2) and b1.width > 0 and b2.width > 0:
                out.append(f"{ax.get_title() or 'axes'} {name}: {s1!r} / {s2!r}")
    return out


def check(fig: Figure, dpi: int = 110, name: str = "figure", drawn: bool = False) -> FigureCheck:
    """The legibility check and the self-check's text problems, from one placement of the text
    (``drawn``: the figure's last draw placed it and nothing changed since)."""
    from reports.shared import layout  # heavy: matplotlib
    sizes = text_sizes_px(fig, dpi)
    # the finishing draw's measured boxes when it was the last draw: the texts are not measured twice
    boxes = layout.last_boxes(fig) if drawn else None
    arts = text_artists(fig, draw=not drawn) if boxes is None else None
    return FigureCheck(min(sizes) if sizes else 0.0, tuple(tick_overlaps(fig, arts, boxes)),
                       int(fig.get_figwidth() * dpi), tuple(figure_text_problems(fig, name, arts=arts, boxes=boxes)))


def save(fig: Figure, path, dpi: int = 110) -> FigureCheck:
    """Write ``fig`` as PNG atomically (temp name + rename); return its legibility check."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: figures are written as .png")
    from reports.shared import layout  # heavy: matplotlib
    layout.finish_figure(fig)   # no text overlaps or leaves the canvas, whatever the data (see layout.py)
    freeze_layout(fig, relayout=not layout.ended_on_draw(fig))
    # checked as placed by that last draw: the PNG below draws the same frozen layout
    chk = check(fig, dpi, path.name, drawn=True)
    # The tight box (it keeps outside legends and edge labels from being clipped), measured in
    # inches from that placement too: "tight" would lay the figure out once more to measure it.
    tight = fig.get_tightbbox(fig.canvas.get_renderer()).padded(0.06)
    with atomic_path(path) as tmp:
        # No creation timestamp in the metadata: the same results give the same bytes.
        fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": None}, bbox_inches=tight)
    return chk


def mgr_axis(ax, values, axis: str = "y") -> None:
    """A symmetric-log axis for log10 MGR values (or their differences) with a few decade ticks
    (0, ±1, ±10^k every few decades) so labels never run together."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    top = float(np.max(np.abs(v))) if v.size else 1.0
    kmax = max(int(math.ceil(math.log10(max(top, 1.0)))), 1)
    step = max(1, math.ceil(kmax / 4))
    dec = [10.0 ** k for k in range(0, kmax + 1, step)]
    ticks = sorted({0.0, *dec, *([-d for d in dec] if v.size and v.min() < 0 else [])})
    set_scale = ax.set_yscale if axis == "y" else ax.set_xscale
    set_scale("symlog", linthresh=MGR_LINTHRESH, linscale=0.6)
    a = ax.yaxis if axis == "y" else ax.xaxis
    a.set_major_locator(FixedLocator(ticks))
    a.set_minor_locator(NullLocator())
    a.set_major_formatter(FuncFormatter(_decade_label))
    lim = 10.0 ** (kmax + 0.15) if top > 1 else 1.5
    low = -lim if v.size and v.min() < 0 else -0.1 * lim if top <= 1 else -0.5
    (ax.set_ylim if axis == "y" else ax.set_xlim)(low, lim)


def _decade_label(x: float, _pos=None) -> str:
    if x == 0:
        return "0"
    k = math.log10(abs(x))
    sign = "−" if x < 0 else ""
    return f"{sign}{plain(abs(x))}" if abs(x) < 1e3 else f"{sign}1e{int(round(k))}"



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
                        label=(f"{label}: {plain(p)}–{plain(100 - p)}%" if label and i == 0 else None))
    ax.plot(x, q[50.0], color=_darken(color, 0.55), linewidth=2.0, drawstyle="steps-mid",
            label=(f"{label}: median" if label else None))


def _darken(color: str, factor: float) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb
    r, g, b = to_rgb(color)
    return (r * factor, g * factor, b * factor)
