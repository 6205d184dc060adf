"""``viewfuse compare RUN_OR_DIR ...``: finished runs side by side, in the terminal and as a page.

Not a stage (no manifest, nothing cached): it reads the runs' ``evaluate/summary.json`` and
manifests (``reports/compare/runs.py``) and writes ``<out>/index.html`` (default: ``compare/`` inside
the first run's folder).
"""
from __future__ import annotations

import sys
from pathlib import Path

from reports.compare.runs import CompareError, compare
from reports.compare.page import render_text, write_page


def default_out(first: str | Path) -> Path:
    return Path(first) / "compare"


def run(paths: list[str], out: str | None = None) -> int:
    try:
        c = compare(paths)
    except CompareError as e:
        print(f"viewfuse compare: error: {e}", file=sys.stderr)
        return 1
    print(render_text(c), end="")
    page = write_page(c, out or default_out(paths[0]))
    print(f"[compare] -> {page}")
    return 0
