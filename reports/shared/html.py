"""A small self-contained HTML report: sections, paragraphs, figures, tables, preformatted text.

The page must work opened straight from disk on a machine with no network: the CSS is inline,
there are no scripts or web fonts, and figures are PNG files referenced by a relative name (they
live next to ``index.html``). Shared by the main report and the simulation report so both look
the same.
"""
from __future__ import annotations

import html
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.infra.cache import atomic_path
from reports.shared.numbers import MISSING, Estimate, fmt, typeset

_CSS = """
:root { --ink:#1d2330; --muted:#5b6475; --line:#d9dde5; --bg:#ffffff; --panel:#f6f7f9;
        --accent:#1f5fa8; }
* { box-sizing: border-box; }
body { margin:0; background:var(--bg); color:var(--ink);
       font: 15px/1.5 system-ui, -apple-system, "Segoe UI", "DejaVu Sans", Arial, sans-serif; }
header { background:#1d2a3f; color:#fff; padding:22px 32px 18px; }
header h1 { margin:0 0 4px; font-size:26px; font-weight:600; }
header p { margin:0; color:#c9d3e3; }
nav { background:var(--panel); border-bottom:1px solid var(--line); padding:8px 32px; font-size:14px;
      display:flex; flex-wrap:wrap; gap:4px 18px; }
nav a { color:var(--accent); text-decoration:none; white-space:nowrap; }
nav a:hover { text-decoration:underline; }
main { max-width:1340px; margin:0 auto; padding:8px 32px 48px; }
section { border-bottom:1px solid var(--line); padding:10px 0 18px; }
section:last-child { border-bottom:none; }
h2 { font-size:21px; margin:18px 0 8px; color:#17325a; }
p { margin:8px 0; max-width:920px; }
p.note { color:var(--muted); font-size:14px; }
p.warn { background:#fff4e0; border-left:4px solid #e09a1a; padding:6px 10px; }
figure { margin:14px 18px 14px 0; display:inline-table; vertical-align:top; max-width:100%; }
figure img { max-width:100%; height:auto; border:1px solid var(--line); background:#fff; }
figcaption { display:table-caption; caption-side:bottom; color:var(--muted); font-size:13.5px;
             margin-top:4px; }
.tablewrap { display:inline-block; vertical-align:top; margin-right:24px; max-width:100%;
             overflow-x:auto; }
table { border-collapse:collapse; margin:10px 0 4px; font-size:14px; }
caption { caption-side:top; text-align:left; color:var(--muted); font-size:13.5px; padding-bottom:4px; }
th, td { border:1px solid var(--line); padding:4px 9px; text-align:left; vertical-align:top; }
th { background:var(--panel); font-weight:600; }
tbody th { font-weight:500; background:#fbfbfc; }
td.num { text-align:right; font-size:13px; font-variant-numeric:tabular-nums; font-family:ui-monospace,"DejaVu Sans Mono",monospace; }
tr:nth-child(even) td { background:#fbfbfc; }
span.nw { white-space:nowrap; }
table.hyperparameters { font-size:12.5px; }
table.hyperparameters td.num { font-size:12px; }
td.changed { background:#fde2e2 !important; font-weight:600; }
dl.glossary { display:grid; grid-template-columns: minmax(8em, 15em) 1fr; gap:4px 16px; max-width:1100px; }
dl.glossary dt { font-weight:600; }
dl.glossary dd { margin:0; }
p.bottomline { font-size:17px; max-width:1060px; background:#eef4fb; border-left:4px solid var(--accent);
               padding:8px 12px; }
table.summary th:first-child, table.summary td:nth-child(2) { white-space:nowrap; }
table.facts th:first-child { font-weight:600; background:var(--panel); white-space:nowrap; }
pre { background:var(--panel); border:1px solid var(--line); padding:10px 12px; overflow-x:auto;
      font: 12.5px/1.4 ui-monospace, "DejaVu Sans Mono", monospace; max-height:520px; }
.precap { color:var(--muted); font-size:13.5px; margin:10px 0 2px; }
details { margin:8px 0; }
details > summary { cursor:pointer; color:var(--accent); }
ul.verdict { font-size:16px; margin:8px 0 12px; padding-left:22px; max-width:980px; }
ul.verdict li { margin:3px 0; }
p.context { font-size:16px; max-width:1000px; }
.tag { display:inline-block; background:#e09a1a; color:#1d2330; font-weight:600; font-size:13px;
       border-radius:3px; padding:1px 7px; margin-left:8px; vertical-align:middle; }
footer { color:var(--muted); font-size:12.5px; padding:16px 32px; border-top:1px solid var(--line); }
"""

# A URL scheme ("http:", "data:", "file:") or an absolute path would break "works from disk".
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def _slug(text: str) -> str:
    s = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return s or "section"


def format_cell(value: Any) -> tuple[str, bool]:
    """Cell text and whether it is numeric (right-aligned): floats and estimates via
    ``reports.shared.numbers`` (significant digits, one format for the whole page)."""
    if value is None:
        return MISSING, False
    if isinstance(value, Estimate):
        return value.text(), True
    if isinstance(value, bool):
        return ("yes" if value else "no"), False
    if isinstance(value, int):
        return str(value), True
    if isinstance(value, float) or hasattr(value, "dtype"):
        try:
            v = float(value)
        except (TypeError, ValueError):
            return str(value), False
        return fmt(v), True
    return str(value), False


@dataclass
class _Section:
    title: str
    anchor: str
    parts: list[str] = field(default_factory=list)


class HtmlReport:
    """Build a report page section by section, then ``write`` it atomically.

    Text is HTML-escaped (pass ``html=True`` to ``paragraph`` for trusted markup built by the
    caller). Figures are PNG names relative to the HTML file.
    """

    def __init__(self, title: str, subtitle: str = "", badge: str = ""):
        self.title = title
        self.subtitle = subtitle
        self.badge = badge  # a short tag beside the title, e.g. "synthetic data"
        self._intro: list[str] = []
        self._sections: list[_Section] = []
        self._anchors: set[str] = set()
        self.figures: list[str] = []  # PNG names referenced, in order (tests and callers check them)

    # -- structure --------------------------------------------------------------------------
    def section(self, title: str, text: str = "", anchor: str | None = None) -> None:
        base = _slug(anchor or title)
        a, n = base, 2
        while a in self._anchors:  # keep anchors unique so the nav links stay right
            a, n = f"{base}-{n}", n + 1
        self._anchors.add(a)
        self._sections.append(_Section(title, a))
        if text:
            self.paragraph(text)

    def _target(self) -> list[str]:
        return self._sections[-1].parts if self._sections else self._intro

    # -- content ----------------------------------------------------------------------------
    def paragraph(self, text: str, *, cls: str = "", html: bool = False) -> None:
        body = text if html else _esc(text)
        c = f' class="{_esc(cls)}"' if cls else ""
        self._target().append(f"<p{c}>{body}</p>")

    def figure(self, png_name: str, caption: str, alt: str = "", min_font_px: float | None = None,
               tick_overlaps: int | None = None, warning: str = "") -> None:
        """A PNG with its caption; ``alt`` states the figure's finding (what a reader who cannot see
        it should learn), ``min_font_px`` the smallest text in the PNG at 100 % (the browser test
        checks that it stays legible at the page's width)."""
        name = str(png_name)
        if _SCHEME.match(name) or name.startswith(("/", "\\")) or ".." in Path(name).parts:
            raise ValueError(f"figure {name!r}: must be a file name relative to the report "
                             "(the page has to work opened from disk)")
        self.figures.append(name)
        font = f' data-min-font-px="{round(float(min_font_px), 1)}"' if min_font_px else ""
        if tick_overlaps is not None:
            font += f' data-tick-overlaps="{int(tick_overlaps)}"'
        # a figure whose text still collides after layout says so, in a box above it
        box = f'<p class="warn figure-warning" role="note">{_esc(warning)}</p>' if warning else ""
        self._target().append(
            f'<figure>{box}<img src="{html.escape(name, quote=True)}" alt="{_esc(alt or caption)}"{font}>'
            f"<figcaption>{_esc(caption)}</figcaption></figure>")

    def definitions(self, items: list[tuple[str, str]], cls: str = "glossary") -> None:
        """A definition list (term, meaning), e.g. the glossary."""
        body = "".join(f"<dt>{_esc(t)}</dt><dd>{_esc(d)}</dd>" for t, d in items)
        self._target().append(f'<dl class="{_esc(cls)}">{body}</dl>')

    def table(self, header: list[str], rows: list[list], caption: str = "", cls: str = "",
              collapsed: str = "", highlight: set[tuple[int, int]] | None = None) -> None:
        """A table; with ``collapsed``, inside a closed <details> whose summary is that text.
        The first column's cells are row headers (``th scope=row``); ``highlight`` holds the
        (row, column) cells to mark as changed."""
        width = len(header)
        for i, r in enumerate(rows):
            if len(r) != width:
                raise ValueError(f"table {caption or header!r}: row {i} has {len(r)} cells, "
                                 f"header has {width}")
        # Wide tables scroll inside their own box instead of widening the page.
        out = ['<div class="tablewrap">' + (f'<table class="{_esc(cls)}">' if cls else "<table>")]
        if caption:
            out.append(f"<caption>{_esc(caption)}</caption>")
        if any(str(h) for h in header):  # an all-empty header means a key/value table: no head row
            out.append("<thead><tr>" + "".join(f'<th scope="col">{_esc(str(h))}</th>' for h in header)
                       + "</tr></thead>")
        out.append("<tbody>")
        marked = highlight or set()
        for i, r in enumerate(rows):
            cells = []
            for j, v in enumerate(r):
                text, numeric = format_cell(v)
                cls_ = " ".join(c for c in ("num" if numeric else "", "changed" if (i, j) in marked else "") if c)
                attr = f' class="{cls_}"' if cls_ else ""
                tag = "th" if j == 0 else "td"
                scope = ' scope="row"' if j == 0 else ""
                cells.append(f"<{tag}{scope}{attr}>{_cell_html(text, numeric)}</{tag}>")
            out.append("<tr>" + "".join(cells) + "</tr>")
        out.append("</tbody></table></div>")
        body = "".join(out)
        if collapsed:
            body = f"<details><summary>{_esc(collapsed)}</summary>{body}</details>"
        self._target().append(body)

    def bullets(self, items: list[str], cls: str = "", collapsed: str = "") -> None:
        """A bulleted list; with ``collapsed``, inside a closed <details> whose summary is that text."""
        c = f' class="{_esc(cls)}"' if cls else ""
        body = f"<ul{c}>" + "".join(f"<li>{_esc(i)}</li>" for i in items) + "</ul>"
        if collapsed:
            body = f"<details><summary>{_esc(collapsed)}</summary>{body}</details>"
        self._target().append(body)

    def preformatted(self, text: str, caption: str = "") -> None:
        cap = f'<div class="precap">{_esc(caption)}</div>' if caption else ""
        self._target().append(f"{cap}<pre>{html.escape(visible(str(text)), quote=True)}</pre>")  # verbatim

    # -- output -----------------------------------------------------------------------------
    def render(self) -> str:
        head = (
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{_esc(self.title)}</title><style>{_CSS}</style></head><body>"
        )
        tag = f'<span class="tag">{_esc(self.badge)}</span>' if self.badge else ""
        hdr = f"<header><h1>{_esc(self.title)}{tag}</h1>"
        if self.subtitle:
            hdr += f"<p>{_esc(self.subtitle)}</p>"
        hdr += "</header>"
        nav = ""
        if len(self._sections) > 1:
            nav = "<nav>" + "".join(f'<a href="#{s.anchor}">{_esc(s.title)}</a>'
                                    for s in self._sections) + "</nav>"
        body = ["<main>"]
        if self._intro:
            body.append("<section>" + "\n".join(self._intro) + "</section>")
        for s in self._sections:
            body.append(f'<section id="{s.anchor}"><h2>{_esc(s.title)}</h2>' + "\n".join(s.parts)
                        + "</section>")
        body.append("</main>")
        foot = f"<footer>Generated by viewfuse on {_esc(time.strftime('%Y-%m-%d %H:%M:%S'))}.</footer>"
        return head + hdr + nav + "\n".join(body) + foot + "</body></html>\n"

    def write(self, path) -> None:
        """Write the page atomically (temp name + rename)."""
        with atomic_path(Path(path)) as tmp:
            tmp.write_text(self.render(), encoding="utf-8")


def _cell_html(text: str, numeric: bool) -> str:
    """A numeric cell breaks only between a value and its '[lo, hi]' interval, so a wide table
    wraps its estimates onto two lines instead of scrolling."""
    if not numeric:
        return _esc(text)
    return " ".join(f'<span class="nw">{_esc(part)}</span>' for part in re.split(r" (?=\[)", text))


# Bidi overrides, embeddings, isolates and marks, and C0/C1 controls but tab and newline: a method
# note or a label from a results file must not reorder or hide what the page shows around it
# (U+202E turns the rest of a cell right-to-left). Each is shown as its code point.
_CONTROLS = re.compile("[\u0000-\u0008\u000b-\u001f\u007f-\u009f\u061c\u200e\u200f\u202a-\u202e"
                       "\u2066-\u2069]")


def visible(text: str) -> str:
    """``text`` with each bidi or control character replaced by a visible '[U+XXXX]'."""
    return _CONTROLS.sub(lambda m: f"[U+{ord(m.group()):04X}]", text)


def _esc(text: str) -> str:
    """Escaped text in the page's one style (``numbers.typeset``: '8 %', the minus sign −), bidi
    and control characters made visible (``visible``)."""
    return html.escape(visible(typeset(str(text))), quote=True)
