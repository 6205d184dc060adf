"""The methods' own models in the report (``pipeline.method.provider``): each enabled provider's
``section`` of its ``models/<key>/index.json``, a note of the diagnostics section (``notes``) or,
with a title, a section of its own (``sections``). The numbers are formatted here, ``Spread`` and
``Interval`` included; the provider says which."""
from __future__ import annotations

from pipeline.method.provider import Interval, Section, Spread
from reports.main.context import ReportContext
from reports.main.instances import category
from reports.shared.numbers import fmt
from pipeline.method.registry import model_providers


def value_text(v):
    """A provider's value as the report shows it (a float with ``fmt``; others as they are)."""
    if isinstance(v, Spread):
        return f"{fmt(v.median)} ({fmt(v.q25)}–{fmt(v.q75)})"
    if isinstance(v, Interval):
        return f"[{fmt(v.lo)}, {fmt(v.hi)}]"
    return fmt(v) if v is None or isinstance(v, float) else v


def filled(template: str, values: dict) -> str:
    """A method's or provider's template with its numbers formatted (counts as they are)."""
    return template.format(**{k: value_text(v) for k, v in values.items()})


def _of(ctx: ReportContext) -> list[tuple[str, list[Section]]]:
    """(provider key, its sections) of every provider with an index in the run."""

    out = []
    for p in model_providers():
        index = (getattr(ctx.run, "provided", None) or {}).get(p.key)
        if not isinstance(index, dict):
            continue
        classes = index.get("classes") or []
        sec = p.section({**index, "categories": {str(c): category(str(c)) for c in classes}})
        if sec is not None:
            out.append((p.key, [sec] if isinstance(sec, Section) else list(sec)))
    return out


def _show(ctx: ReportContext, key: str, parts: list[Section]) -> None:
    for sec in parts:
        if sec.text:
            ctx.page.paragraph(filled(sec.text, sec.values), cls="note" if sec.note else "")
        if sec.rows:
            ctx.page.table(list(sec.columns), [[value_text(v) for v in r] for r in sec.rows],
                           cls=sec.cls or f"{key}-models", collapsed=sec.collapsed, caption=sec.caption)


def notes(ctx: ReportContext) -> None:
    """The untitled sections, in the diagnostics section."""
    for key, parts in _of(ctx):
        if not parts[0].title:
            _show(ctx, key, parts)


def sections(ctx: ReportContext) -> None:
    """The titled sections, each a section of the report."""
    for key, parts in _of(ctx):
        if parts[0].title:
            ctx.section(parts[0].title, parts[0].anchor or f"{key}-models")
            _show(ctx, key, parts)
