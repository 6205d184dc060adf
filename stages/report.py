"""Stage ``report``: re-render index.html + one PNG per figure from existing results.

Reads the run's ``evaluate/`` (results, summary with the population verdict, track, GP rasters,
bias maps), ``models/index.json``, ``classifier/card.json`` and the stages' manifests; computes
nothing but plotting percentiles and the detailed track's CIs over realizations (seeded), so
``make report`` re-renders in seconds.
"""
from __future__ import annotations

import subprocess

from pipeline.infra.config import to_dict
from reports.main.page import build_main_report
from stages.framework.runner import stage_timings


def run(ctx) -> str:
    cfg = ctx.cfg
    res = build_main_report(
        cfg.run_dir, ctx.out,
        title=cfg.report.title, dpi=cfg.report.dpi, run_name=cfg.run.name,
        config=to_dict(cfg), timings=stage_timings(cfg), commit=_commit(cfg.root),
        config_file=_relative(cfg.source_path, cfg.root), strict=cfg.report.strict,
        workers=None,   # independent figures drawn at once on the free cores (reports/main/figure_pool.py)
    )
    ctx.extra["figures"] = res.figures
    ctx.extra["sections"] = res.sections
    ctx.extra["notes"] = res.notes
    ctx.extra["layout_problems"] = res.layout_problems   # figures shown with a warning box
    final = cfg.stage_dir(ctx.stage) / res.index.name
    return f"{res.index.name} + {len(res.figures)} figures; open {final}"


def _commit(root) -> str:
    """The checkout's commit for the reproduce box ('' outside a git checkout)."""
    try:
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=12"],
                             capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def _relative(path: str, root) -> str:
    from pathlib import Path
    if not path:
        return ""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path(root).resolve()))
    except ValueError:
        return str(p)
