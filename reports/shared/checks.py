"""Build-time self-checks of a report: the build fails (``ReportCheckError``) instead of publishing
a page that contradicts itself.

Three checks, each a pure function of what the page is about to show:

- **figure text** (``figure_text_problems``): after layout, every text artist of a figure (suptitle,
  axes titles, axis labels, tick labels, legend entries and titles, free texts) is drawn into a
  box; two boxes that overlap, or a box that leaves the figure canvas, is a problem. Tick labels of
  one axis are compared with their neighbours only, and only where matplotlib draws them (inside
  the axes' span).
- **the ledger** (``Ledger``): every number the page prints for a statistic is registered with its
  key, value, 95 % interval and the label printed next to it. A key shown twice with different
  numbers, a label the interval contradicts ("better" with a CI containing 0, "not
  distinguishable" with one excluding it, "holds" with a CI on the wrong side) or a value outside
  its own interval is a problem.
- **captions state a finding** (``caption_problem``, the rule in ``FINDING_RULE``).
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pipeline.evaluation.statistics.records import outcome
from pipeline.infra.outputs import number

# A caption states a finding when, after removing the CI level ("95 %"), it still holds a number
# (a measured value) and a word that compares (a direction or an outcome). "Paired differences per
# target" fails; "With Uncertainty wins 7 of 12 targets; pooled +0.18 [+0.01, +0.32], better" passes.
FINDING_RULE = ("a caption states a finding when, besides the CI level (95 %), it holds a number and one "
                "of the comparison words: " )
COMPARISON_WORDS = ("better", "worse", "higher", "highest", "lower", "lowest", "more", "less", "fewer", "than", "above", "below",
                    "exceeds", "larger", "largest", "smaller", "smallest", "most", "least", "wins", "loses",
                    "won", "lost", "holds", "hold", "fails", "not distinguishable", "inconclusive", "rises",
                    "falls", "drops", "grows", "same", "equal", "differ", "moves", "reaches", "up to", "at most",
                    "at least", "none", "all", "every")
FINDING_RULE += ", ".join(COMPARISON_WORDS) + "."
_CI_LEVEL = re.compile(r"95\s*%(?:\s*(?:bootstrap\s+)?CIs?)?", re.IGNORECASE)
_NUMBER = re.compile(r"(?<![A-Za-z_])[−+-]?\d+(?:[.,]\d+)?(?:e[−+-]?\d+)?")

# Labels the ledger understands: the side of 0 the interval must lie on (None: it must contain 0).
POSITIVE, NEGATIVE, ZERO = "positive", "negative", "contains 0"
IMPROVES = ("better", "holds")         # the good side of 0 (which side depends on the direction)
WORSENS = ("worse", "fails")
UNDECIDED = ("not distinguishable", "inconclusive", "not distinguishable from 0")


class ReportCheckError(RuntimeError):
    """The report contradicts itself; the message lists every problem found."""

    def __init__(self, problems: Iterable[str]):
        self.problems = list(problems)
        super().__init__("report self-check failed (" + str(len(self.problems)) + " problems):\n  - "
                         + "\n  - ".join(self.problems))


# ---------------------------------------------------------------- figure text

def text_artists(fig, draw: bool = True) -> list[tuple[str, Any, Any]]:
    """(group, text artist, its axes or None) of every visible, non-empty text after layout, in the
    checker's order. ``group`` names the axis a tick label belongs to ('' for every other text);
    only tick labels matplotlib draws (inside the axes' span) are listed. ``draw=False``: the
    caller has just drawn the figure and changed nothing since."""
    # layout and text placement without rasterizing (the boxes are the same; it is several times faster)
    if draw:
        fig.draw_without_rendering()
    r = fig.canvas.get_renderer()
    out: list[tuple[str, Any, Any]] = []
    seen: set[int] = set()

    def add(t, ax=None, group: str = "") -> None:
        if t is not None and id(t) not in seen and t.get_visible() and t.get_text().strip():
            seen.add(id(t))
            out.append((group, t, ax))

    add(getattr(fig, "_suptitle", None))
    add(getattr(fig, "_supxlabel", None))
    add(getattr(fig, "_supylabel", None))
    for t in fig.texts:
        add(t)
    for leg in fig.legends:
        _legend(leg, add)
    for i, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison and not ax.get_title():
            continue
        for t in (ax.title, getattr(ax, "_left_title", None), getattr(ax, "_right_title", None)):
            add(t, ax)
        add(ax.xaxis.label, ax)
        add(ax.yaxis.label, ax)
        for name, labels, (lo, hi) in (("x", ax.get_xticklabels(), (ax.bbox.x0, ax.bbox.x1)),
                                       ("y", ax.get_yticklabels(), (ax.bbox.y0, ax.bbox.y1))):
            for t in labels:
                if not (t.get_visible() and t.get_text().strip()):
                    continue
                b = t.get_window_extent(r)
                mid = (b.x0 + b.x1) / 2 if name == "x" else (b.y0 + b.y1) / 2
                if lo - 2 <= mid <= hi + 2:            # matplotlib draws only these
                    out.append((f"{i}{name}", t, ax))
        for t in ax.texts:
            add(t, ax)
        if ax.get_legend() is not None:
            _legend(ax.get_legend(), lambda t, ax=ax: add(t, ax))
    return out


def _text_boxes(fig, arts=None) -> list[tuple[str, str, Any]]:
    """(group, text, window box) of every text ``text_artists`` lists (``arts``: its list, if the
    caller has just made it)."""
    arts = text_artists(fig) if arts is None else arts
    r = fig.canvas.get_renderer()
    return [(g, t.get_text(), t.get_window_extent(r)) for g, t, _ in arts]


def _legend(leg, add) -> None:
    if not leg.get_visible():
        return
    add(leg.get_title())
    for t in leg.get_texts():
        add(t)


def _short(s: str) -> str:
    s = " ".join(s.split())
    return repr(s if len(s) <= 40 else s[:37] + "...")


def figure_text_problems(fig, name: str = "figure", tol_px: float = 1.0, arts=None, boxes=None) -> list[str]:
    """Text of ``fig`` that overlaps other text or leaves the canvas (after layout). ``arts``:
    ``text_artists(fig)`` made since the figure's last change, to spare a second layout; ``boxes``:
    those texts' (group, text, axes, box) as measured since (``layout.last_boxes``), to spare measuring."""
    boxes = _text_boxes(fig, arts) if boxes is None else [(g, t.get_text(), b) for g, t, _, b in boxes]
    rank = _ranks(boxes)
    W, H = fig.bbox.width, fig.bbox.height
    out = []
    for _, s, b in boxes:
        if b.x0 < -tol_px or b.y0 < -tol_px or b.x1 > W + tol_px or b.y1 > H + tol_px:
            out.append(f"{name}: text {_short(s)} is clipped (its box x {round(b.x0)}–{round(b.x1)}, y {round(b.y0)}–{round(b.y1)} "
                       f"px leaves the {round(W)}×{round(H)} px canvas)")
    for _, s, _b in boxes:
        if "\\mathdefault" in s or "\\times" in s:   # a formatter's mathtext, printed literally (no mathtext)
            out.append(f"{name}: text {_short(s)} prints mathtext markup literally")
    for i, (g1, s1, b1) in enumerate(boxes):
        for g2, s2, b2 in boxes[i + 1:]:
            if g1 and g1 == g2 and abs(rank[id(b1)] - rank[id(b2)]) != 1:
                # tick labels of one axis are compared with the next one along it only
                continue
            ox = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
            oy = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
            if ox > tol_px and oy > tol_px:
                out.append(f"{name}: text {_short(s1)} overlaps {_short(s2)}")
    return out


def _ranks(boxes) -> dict[int, int]:
    """Each tick label box's place along its axis (by its left or bottom edge), per tick group."""
    groups: dict[str, list] = {}
    for g, _, b in boxes:
        if g:
            groups.setdefault(g, []).append(b)
    rank = {}
    for g, bs in groups.items():
        key = (lambda b: b.x0) if g[-1] == "x" else (lambda b: b.y0)
        rank.update((id(b), i) for i, b in enumerate(sorted(bs, key=key)))
    return rank


# ---------------------------------------------------------------- the ledger

@dataclass(frozen=True)
class Entry:
    key: tuple
    value: float | None
    low: float | None
    high: float | None
    label: str
    where: str
    higher_is_better: bool | None


def _same(a: float | None, b: float | None, rel: float = 1e-9) -> bool:
    if a is None or b is None:
        return a is b
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= rel * max(abs(a), abs(b), 1e-300)


@dataclass
class Ledger:
    """Every statistic the page prints: one key, one (value, CI), one label."""
    entries: list[Entry] = field(default_factory=list)

    def register(self, key, value=None, low=None, high=None, *, label: str = "", where: str = "",
                 higher_is_better: bool | None = None) -> None:
        """Record a printed statistic. ``key`` names the statistic (e.g. ('paired', comparison,
        metric)); ``label`` is the word printed with it (better / worse / not distinguishable /
        holds / fails / inconclusive, or '')."""
        self.entries.append(Entry(tuple(key) if isinstance(key, (tuple, list)) else (key,),
                                  number(value, None, None), number(low, None, None), number(high, None, None),
                                  str(label or "").strip().lower(), where, higher_is_better))

    def register_estimate(self, key, d: dict | None, **kw) -> None:
        d = d or {}
        self.register(key, d.get("value"), d.get("ci_low"), d.get("ci_high"), **kw)

    def register_row(self, key, names, shown, source: Mapping | None, *, where: str,
                     source_where: str = "evaluate/summary.json") -> None:
        """A table row's numbers, each against its source (one statistic per number): cell i
        (``shown[i]``: a number or an ``Estimate``) and ``source[names[i]]`` (a number or an
        estimate mapping) under ``key + (names[i],)``, so a cell that is not its source's number
        is a problem."""
        source = source or {}
        for name, cell in zip(names, shown):
            k = (*key, name)
            self.register(k, *_triple_of(source.get(name)), where=source_where)
            self.register(k, *_triple_of(cell), where=where)

    def register_record(self, key, shown, rec: Mapping | None, *, where: str,
                        record_where: str = "its verdict record (evaluate/summary.json)") -> None:
        """A shown paired difference (an ``Estimate`` or estimate mapping) against the verdict
        record it is read with (value, lo, hi, outcome: the record's label is checked against its
        interval), both under ``key``; ``shown`` None: the record's label alone (an outcome word)."""
        if rec is not None:
            better = rec.get("better")
            self.register(key, rec.get("value"), rec.get("lo"), rec.get("hi"), label=str(rec.get("outcome") or ""),
                          where=record_where, higher_is_better=None if better is None else better == "higher")
        if shown is not None:
            self.register(key, *_triple_of(shown), where=where)

    def problems(self) -> list[str]:
        out = [p for e in self.entries for p in label_problems(e)]
        first: dict[tuple, Entry] = {}
        for e in self.entries:
            if e.key not in first:
                first[e.key] = e
                continue
            f = first[e.key]
            if not (_same(e.value, f.value) and _same(e.low, f.low) and _same(e.high, f.high)):
                out.append(f"{_key(e.key)}: {f.where} shows {_triple(f)} but {e.where} shows {_triple(e)}")
            elif e.label and f.label and _kind(e.label) != _kind(f.label):
                out.append(f"{_key(e.key)}: {f.where} says {f.label!r} but {e.where} says {e.label!r}")
        return out


def _triple_of(x) -> tuple:
    """(value, low, high) of a shown or stored number: an ``Estimate``, an estimate mapping
    (ci_low / ci_high, or a record's lo / hi) or a bare number (no interval)."""
    if isinstance(x, Mapping):
        return x.get("value"), x.get("ci_low", x.get("lo")), x.get("ci_high", x.get("hi"))
    if hasattr(x, "low") and hasattr(x, "high"):
        return x.value, x.low, x.high
    return x, None, None


def _kind(label: str) -> str:
    return "up" if label in IMPROVES else "down" if label in WORSENS else "zero" if label in UNDECIDED else label


def _key(key: tuple) -> str:
    return " / ".join(str(k) for k in key)


def _triple(e: Entry) -> str:
    return f"{e.value} [{e.low}, {e.high}]"


def label_problems(e: Entry) -> list[str]:
    """Where a printed label or value disagrees with its own interval."""
    out = []
    lo, hi, v = e.low, e.high, e.value
    if lo is None or hi is None:
        if e.label in IMPROVES + WORSENS:
            out.append(f"{_key(e.key)} ({e.where}): labelled {e.label!r} without an interval")
        return out
    if lo > hi:
        out.append(f"{_key(e.key)} ({e.where}): interval [{lo}, {hi}] is reversed")
    if v is not None and not (lo - 1e-12 * max(1.0, abs(lo)) <= v <= hi + 1e-12 * max(1.0, abs(hi))):
        out.append(f"{_key(e.key)} ({e.where}): value {v} lies outside its own interval [{lo}, {hi}]")
    if not e.label:
        return out
    side = POSITIVE if lo > 0 else NEGATIVE if hi < 0 else ZERO
    if e.label in UNDECIDED:
        if side != ZERO:
            out.append(f"{_key(e.key)} ({e.where}): labelled {e.label!r} but its interval [{lo}, {hi}] excludes 0")
        return out
    if e.label in IMPROVES + WORSENS:
        if side == ZERO:
            out.append(f"{_key(e.key)} ({e.where}): labelled {e.label!r} but its interval [{lo}, {hi}] contains 0")
        elif e.higher_is_better is not None:
            good = (side == POSITIVE) == e.higher_is_better
            if good != (e.label in IMPROVES):
                out.append(f"{_key(e.key)} ({e.where}): labelled {e.label!r} but its interval [{lo}, {hi}] lies on "
                           f"the {'good' if good else 'bad'} side of 0")
    return out


def outcome_of(low, high, higher_is_better: bool, words=("better", "worse", "not distinguishable")) -> str:
    """The one outcome rule (``records.outcome``: the side of 0 the interval lies on; a JSON null
    end is unbounded) in ``words``."""
    res = outcome(number(low, None), number(high, None), higher_is_better)
    return words[("better", "worse", "not distinguishable").index(res)]


# ---------------------------------------------------------------- captions

def caption_problem(name: str, caption: str) -> str:
    """'' when ``caption`` states a finding (``FINDING_RULE``), else the problem."""
    rest = _CI_LEVEL.sub(" ", caption or "")
    has_number = bool(_NUMBER.search(rest))
    low = rest.lower()
    has_word = any(re.search(r"(?<![a-z])" + re.escape(w) + r"(?![a-z])", low) for w in COMPARISON_WORDS)
    if has_number and has_word:
        return ""
    missing = " and ".join(x for x, ok in (("a number", has_number), ("a comparison word", has_word)) if not ok)
    return f"{name}: caption states no finding (it lacks {missing}): {_short(caption)}"


# ---------------------------------------------------------------- plain words

# Internal names a reader should never meet on a page (config keys and code names are shown only
# in the run details' configuration dump and the reproduce box, which the walk skips).
INTERNAL_NAMES = (r"\bWU\b", r"\bN_x\b", r"\bN_ss\b", r"\bN_f\b", r"cross_fit", r"top_mean", r"top_min",
                  r"population\.\w+", r"\bissue \d+", "`", r"\w\(s\)", r"summary\.json's", r"_final\b",
                  r"_overall\b", r"\bverdict_table\b", r"\bpaired_per_target\b")
_ASCII_MINUS = re.compile(r"(?<![\w./-])-(?=\d)")   # '-0.3' (a hyphen used as a minus sign)
_TIGHT_PERCENT = re.compile(r"\d%")                 # '8%' (the page writes '8 %')


def page_text(html_text: str, skip_classes: tuple[str, ...] = ("config", "facts", "config-diff", "json-paths",
                                                                 "hyperparameters", "reproduce")) -> list[str]:
    """The visible text of a page, chunk by chunk, outside <pre>, <style>, <code> and the tables
    whose class names a place that shows code names on purpose (``skip_classes``)."""
    from html.parser import HTMLParser

    class Walk(HTMLParser):
        def __init__(self):
            super().__init__()
            self.skip, self.stack, self.out = 0, [], []

        def handle_starttag(self, tag, attrs):
            if tag in ("br", "img", "meta", "link", "hr", "input"):
                return
            cls = (dict(attrs).get("class") or "").split()
            sect = dict(attrs).get("id") or ""
            hide = tag in ("pre", "style", "code", "script") or any(c in skip_classes for c in cls) \
                or sect in skip_classes
            self.stack.append(hide)
            self.skip += hide

        def handle_endtag(self, tag):
            if tag in ("br", "img", "meta", "link", "hr", "input") or not self.stack:
                return
            self.skip -= self.stack.pop()

        def handle_data(self, data):
            if not self.skip and data.strip():
                self.out.append(data)

    w = Walk()
    w.feed(html_text)
    return w.out


def plain_words_problems(html_text: str) -> list[str]:
    """Internal names, hyphen-minus signs and '8%' in a page's visible text."""
    out = []
    for chunk in page_text(html_text):
        for pat in INTERNAL_NAMES:
            m = re.search(pat, chunk)
            if m:
                out.append(f"internal name {m.group(0)!r} in: {_short(chunk[max(0, m.start() - 30):m.end() + 30])}")
        for rx, what in ((_ASCII_MINUS, "a hyphen as minus sign"), (_TIGHT_PERCENT, "'%' without a space")):
            m = rx.search(chunk)
            if m:
                out.append(f"{what} in: {_short(chunk[max(0, m.start() - 30):m.end() + 30])}")
    return out
