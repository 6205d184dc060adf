"""Figure text that cannot collide: after a draw, every text's rendered box is read and the figure
is changed until no two texts overlap and none leaves the canvas (the rule of
``reports.shared.checks.figure_text_problems``), whatever the data were.

``finish_figure`` runs a few rounds of draw → measure → fix. The fixes, mildest first:

- tick labels of one axis that touch: a category axis (names set by hand) gets more room (a taller
  canvas for rows, narrower wrapping for columns); a numeric axis (linear, log, symlog) keeps its
  ticks but labels every n-th only, anchored at 0 where 0 is a tick, n growing until the labels
  keep apart;
- titles, axis labels and free texts that run into a neighbour or past the canvas are wrapped to
  the width they have (long words broken, never cut);
- a legend that collides has fewer columns, or leaves the axes for their right-hand side;
- text that leaves the canvas while it would fit grows the canvas on that side (height freely,
  width up to ``MAX_WIDTH_IN``, beyond it only when wrapping could not help);
- what still collides is set at the smallest legible size (``MIN_FONT_PT``).

Every figure of the reports goes through it: ``reports.shared.figures.save`` calls it before it
writes the PNG.
"""
from __future__ import annotations

import functools
import textwrap
import weakref
from matplotlib.text import Annotation
from matplotlib.ticker import FixedFormatter, Formatter

from reports.shared.checks import text_artists

MAX_ROUNDS = 12
# figures whose last finish_figure ended on a measuring draw, nothing changed since (save reads
# their text where that draw placed it instead of laying them out again)
_ENDED_ON_DRAW: weakref.WeakSet = weakref.WeakSet()
# and the (group, text, axes, box) that draw measured, for the checks to read instead of measuring again
_LAST_BOXES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
MAX_HEIGHT_IN = 80.0
MIN_FONT_PT = 8.0
MAX_WIDTH_IN = 10.8          # as reports.shared.figures (the page's width at 100 %)
HARD_MAX_WIDTH_IN = 24.0     # the last resort, when wrapping cannot make text fit
TOL_PX = 1.0


class ThinnedFormatter(Formatter):
    """Another formatter's labels at every ``stride``-th tick only (anchored at the tick at 0, else
    at the first), the rest blank: the ticks and grid stay, their labels no longer touch."""

    def __init__(self, inner: Formatter, stride: int):
        self.inner, self.stride = inner, max(1, int(stride))

    def set_axis(self, axis):
        super().set_axis(axis)
        self.inner.set_axis(axis)

    def set_locs(self, locs):
        self.locs = locs
        self.inner.set_locs(locs)

    def __call__(self, x, pos=None):
        return self.inner(x, pos)

    def format_ticks(self, values):
        labels = self.inner.format_ticks(values)
        vals = list(values)
        if not vals:
            return labels
        lo, hi = self.axis.get_view_interval() if self.axis is not None else (min(vals), max(vals))
        lo, hi = min(lo, hi), max(lo, hi)
        shown = [i for i, v in enumerate(vals) if lo - 1e-12 * abs(lo) <= v <= hi + 1e-12 * abs(hi)] or \
            list(range(len(vals)))
        zero = [i for i in shown if vals[i] == 0]
        anchor = zero[0] if zero else shown[0]
        return [s if (i - anchor) % self.stride == 0 else "" for i, s in enumerate(labels)]

    def get_offset(self):
        return self.inner.get_offset()


def _axis(ax, name: str):
    return ax.xaxis if name == "x" else ax.yaxis


def _thin(ax, name: str) -> bool:
    """One step more thinning on ``ax``'s ``name`` axis; False when nothing is left to thin."""
    a = _axis(ax, name)
    fmt = a.get_major_formatter()
    if isinstance(fmt, ThinnedFormatter):
        n_shown = sum(1 for t in (ax.get_xticklabels() if name == "x" else ax.get_yticklabels())
                      if t.get_text().strip())
        if n_shown <= 1:     # a squeezed axis (equal aspect) may keep one label only
            return False
        fmt.stride += 1
        a.stale = True
        return True
    a.set_major_formatter(ThinnedFormatter(fmt, 2))
    return True


def _wrap_text(s: str, chars: int) -> str:
    chars = max(4, int(chars))
    out = []
    for para in s.split("\n"):
        out.extend(textwrap.wrap(para, chars, break_long_words=True, break_on_hyphens=True) or [""])
    return "\n".join(out)


def _longest_line(s: str) -> int:
    return max((len(x) for x in s.split("\n")), default=0)


def _narrow(t, width_px: float, box) -> bool:
    """Wrap text ``t`` so that its box is at most ``width_px`` wide; False when it cannot get narrower."""
    s = t.get_text()
    n = _longest_line(s)
    if n <= 4 or box.width <= 0:
        return False
    chars = int(n * min(width_px / box.width, 0.85))
    if chars >= n:
        chars = n - 1
    if chars < 4:
        return False
    new = _wrap_text(s, chars)
    if new == s:
        return False
    t.set_text(new)
    return True


def _shrink(t) -> bool:
    size = t.get_fontsize()
    if size <= MIN_FONT_PT + 0.01:
        return False
    t.set_fontsize(max(MIN_FONT_PT, size * 0.88))
    return True


def _grow(fig, dw_in: float = 0.0, dh_in: float = 0.0, last_resort: bool = False) -> bool:
    w, h = fig.get_size_inches()
    cap = HARD_MAX_WIDTH_IN if last_resort else max(MAX_WIDTH_IN, w)
    nw = min(w + max(dw_in, 0.0), cap)
    nh = min(h + max(dh_in, 0.0), MAX_HEIGHT_IN)
    if nw <= w + 1e-6 and nh <= h + 1e-6:
        return False
    fig.set_size_inches(nw, nh, forward=False)
    return True


def _categorical(ax, name: str):
    """The names of a category axis (labels set by hand: ``set_ticklabels``), as a mutable
    {tick: label} dict or list; None for a numeric axis."""
    fmt = _axis(ax, name).get_major_formatter()
    if isinstance(fmt, FixedFormatter):
        return fmt.seq
    func = getattr(fmt, "func", None)
    if isinstance(func, functools.partial) and func.args and isinstance(func.args[0], dict):
        return func.args[0]
    return None


def _fix_category_ticks(fig, ax, name: str, pairs, dpi: float) -> bool:
    """Names on a category axis keep every label: rows get a taller canvas, columns wrap narrower."""
    names = _categorical(ax, name)
    if name == "y":
        need = max(min(b1.y1, b2.y1) - max(b1.y0, b2.y0) for b1, b2 in pairs)
        n = max(len(names), 1)
        if _grow(fig, dh_in=min((max(need, 2.0) + 3.0) * n / dpi * 1.3, 20.0)):
            return True
    else:
        keys = list(names.keys()) if isinstance(names, dict) else list(range(len(names)))
        n = max((_longest_line(str(names[k])) for k in keys), default=0)
        if n > 6:
            for k in keys:
                names[k] = _wrap_text(str(names[k]), max(6, int(n * 0.7)))
            _axis(ax, name).stale = True
            return True
    labels = ax.get_xticklabels() if name == "x" else ax.get_yticklabels()
    if any(_shrink(t) for t in labels):
        ax.tick_params(axis=name, labelsize=max(MIN_FONT_PT, labels[0].get_fontsize()))
        return True
    return _thin(ax, name)


def _legend_of(t, fig):
    for leg in list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]:
        if t in leg.get_texts() or t is leg.get_title():
            return leg
    return None


def _fix_legend(fig, leg, done: set) -> bool:
    if id(leg) in done:
        return False
    done.add(id(leg))
    ncol = getattr(leg, "_ncols", 1)
    if ncol > 1:
        leg.set_ncols(max(1, ncol // 2))
        return True
    ax = leg.axes if leg.axes is not None and leg in [a.get_legend() for a in fig.axes] else None
    if ax is not None and getattr(leg, "_viewfuse_moved", False) is False:
        leg._viewfuse_moved = True
        leg.set_loc("upper left")
        leg.set_bbox_to_anchor((1.01, 1.0), transform=ax.transAxes)
        return True
    changed = False
    for t in leg.get_texts():
        changed |= _shrink(t)
    return changed


def _room_for(t, ax, fig, r) -> float:
    """Width (px) a text may take: its axes' width for an axes title, else the canvas'."""
    if ax is not None and t in (ax.title, getattr(ax, "_left_title", None), getattr(ax, "_right_title", None)):
        return max(ax.bbox.width * 1.05, 40.0)
    return fig.bbox.width * 0.96


def _problems(fig):
    """(tick groups with touching neighbours, clipped texts, overlapping pairs) after a draw."""
    arts = text_artists(fig)
    r = fig.canvas.get_renderer()
    boxes = [(g, t, ax, t.get_window_extent(r)) for g, t, ax in arts]
    _LAST_BOXES[fig] = boxes
    W, H = fig.bbox.width, fig.bbox.height
    clipped = [(t, ax, b) for _, t, ax, b in boxes
               if b.x0 < -TOL_PX or b.y0 < -TOL_PX or b.x1 > W + TOL_PX or b.y1 > H + TOL_PX]
    ticks: dict[tuple, list] = {}
    groups: dict[str, list] = {}
    for g, t, ax, b in boxes:
        if g:
            groups.setdefault(g, []).append((t, ax, b))
    for g, items in groups.items():
        key = (lambda it: it[2].x0) if g[-1] == "x" else (lambda it: it[2].y0)
        items.sort(key=key)
        for (t1, ax, b1), (t2, _, b2) in zip(items, items[1:]):
            if _touch(b1, b2):
                ticks.setdefault((ax, g[-1]), []).append((b1, b2))
    pairs = []
    for i, (g1, t1, ax1, b1) in enumerate(boxes):
        for g2, t2, ax2, b2 in boxes[i + 1:]:
            if g1 and g1 == g2:
                continue
            if _touch(b1, b2):
                pairs.append(((g1, t1, ax1, b1), (g2, t2, ax2, b2)))
    return ticks, clipped, pairs, r


def _touch(b1, b2) -> bool:
    ox = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
    oy = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
    return ox > TOL_PX and oy > TOL_PX


def _fix_clipped(fig, t, ax, b, r, last_resort: bool) -> bool:
    W, H = fig.bbox.width, fig.bbox.height
    dpi = fig.dpi
    if b.height > H - 4:
        return _grow(fig, dh_in=(b.height - H) / dpi + 0.6)
    if b.width > W * 0.98 and not _is_tick(t, ax):
        if _grow(fig, dw_in=(b.width - W) / dpi + 0.3) and not last_resort:
            return True
        if _narrow(t, W * 0.9, b):
            return True
    out_x = max(-b.x0, b.x1 - W, 0.0)
    out_y = max(-b.y0, b.y1 - H, 0.0)
    if out_y > 0 and _grow(fig, dh_in=out_y / dpi * 1.5 + 0.2):
        return True
    if out_x > 0:
        if _grow(fig, dw_in=out_x / dpi * 1.5 + 0.2):
            return True
        if not _is_tick(t, ax) and _narrow(t, max(b.width - out_x - 8, 20.0), b):
            return True
        if last_resort and _grow(fig, dw_in=out_x / dpi * 1.5 + 0.2, last_resort=True):
            return True
    return _shrink(t) if not _is_tick(t, ax) else False


def _is_tick(t, ax) -> bool:
    return ax is not None and (t in ax.get_xticklabels() or t in ax.get_yticklabels())


def _point_label(t) -> bool:
    return isinstance(t, Annotation) and t.xycoords == "data"


def _fix_pair(fig, p1, p2, r, done: set, legends: set) -> bool:
    """Two texts (not neighbouring ticks of one axis) that touch: wrap, move or shrink one of them.
    Two labels of data points (annotations anchored in data coordinates, e.g. camera numbers)
    that touch are thinned like ticks: the later one is hidden, the first keeps its point named."""
    if all(_point_label(t) for _, t, _, _ in (p1, p2)):
        p2[1].set_visible(False)
        return True
    for g, t, ax, b in (p1, p2):
        if id(t) in done:
            continue
        leg = _legend_of(t, fig)
        if leg is not None:
            if _fix_legend(fig, leg, legends):
                done.add(id(t))
                return True
            continue
        if g:                                   # a tick label: the other text moves, or its axis thins
            continue
        done.add(id(t))
        if _narrow(t, min(_room_for(t, ax, fig, r), b.width * 0.8), b) or _shrink(t):
            return True
    for g, t, ax, b in (p1, p2):
        if g and (ax, g[-1]) not in done:
            done.add((ax, g[-1]))
            if _categorical(ax, g[-1]) is None and _thin(ax, g[-1]):
                return True
    return _grow(fig, dh_in=0.5)


def finish_figure(fig) -> list[str]:
    """Change ``fig`` until no text overlaps another or leaves the canvas (at most ``MAX_ROUNDS``
    draws); returns what it changed, one line per round (empty when the figure was clean)."""
    log: list[str] = []
    _ENDED_ON_DRAW.discard(fig)
    _LAST_BOXES.pop(fig, None)
    for rnd in range(MAX_ROUNDS):
        ticks, clipped, pairs, r = _problems(fig)
        if not ticks and not clipped and not pairs:
            _ENDED_ON_DRAW.add(fig)
            return log
        last = rnd >= MAX_ROUNDS // 2
        changed = []
        for (ax, name), tp in ticks.items():
            fixed = (_fix_category_ticks(fig, ax, name, tp, fig.dpi) if _categorical(ax, name) is not None
                     else _thin(ax, name))
            if fixed:
                changed.append(f"{ax.get_title() or 'axes'} {name}: ticks")
        for t, ax, b in clipped:
            if _fix_clipped(fig, t, ax, b, r, last):
                changed.append(f"clipped {t.get_text()[:20]!r}")
                break                            # the canvas changed: measure again
        done: set = set()
        legends: set = set()
        for p1, p2 in pairs:
            if _fix_pair(fig, p1, p2, r, done, legends):
                changed.append(f"overlap {p1[1].get_text()[:20]!r} / {p2[1].get_text()[:20]!r}")
        if not changed:
            _ENDED_ON_DRAW.add(fig)
            break
        log.append("; ".join(changed))
    return log


def ended_on_draw(fig) -> bool:
    """Whether ``finish_figure``'s last act on ``fig`` was a draw, with nothing changed since."""
    return fig in _ENDED_ON_DRAW


def last_boxes(fig) -> list | None:
    """The (group, text, axes, box) of every checked text as ``finish_figure``'s last draw placed
    them, when that draw was its last act (``ended_on_draw``); else None."""
    return _LAST_BOXES.get(fig) if fig in _ENDED_ON_DRAW else None
