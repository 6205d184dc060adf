"""The view-planning rows of ``viewfuse compare``: each run's pooled planning metrics and its
paired planning verdicts, read from the ``planning`` block of its summary.json (as the evaluate
stage wrote them, never recomputed). A seed group's pooled column shows none: its seeds' runs
have their own columns."""
from __future__ import annotations

ORDER = ("steps_to_decision", "correct_at_3", "correct_at_5", "correct_at_10", "confident_error_at_10", "nll_at_10")


def block_of(summary) -> dict | None:
    """The planning block of a summary.json (None when it has none)."""
    block = summary.get("planning") if isinstance(summary, dict) else None
    return block if isinstance(block, dict) and isinstance(block.get("pooled"), dict) else None


def rows(blocks: list[dict | None]) -> tuple[list[tuple[str, str, list[dict | None]]], list[tuple[str, str, list]]]:
    """([(planner, metric, per-column estimate)], [(comparison, metric, per-column estimate with outcome)])."""
    have = [b for b in blocks if b]
    if not have:
        return [], []
    planners = list(dict.fromkeys(p for b in have for p in b.get("planners", b["pooled"])))
    metrics = [m for m in ORDER if any(m in (b["pooled"].get(p) or {}) for b in have for p in planners)]
    pooled = [(p, m, [((b or {}).get("pooled", {}).get(p) or {}).get(m) for b in blocks])
              for m in metrics for p in planners]
    comps = list(dict.fromkeys(k for b in have for k in b.get("paired", {})))
    paired = [(k, m, [((b or {}).get("paired", {}).get(k) or {}).get(m) for b in blocks])
              for k in comps for m in ("steps_to_decision", "correct_at_3", "correct_at_5", "correct_at_10")
              if any(((b or {}).get("paired", {}).get(k) or {}).get(m) for b in blocks)]
    return pooled, paired
