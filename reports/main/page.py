"""The main report: reads a run's artifacts and renders index.html + PNGs.

Page order answers the question first: the verdict (population, with CIs), where the method wins
and loses per target, what drives the result (GP fits at a bound, ablations), then the paper's
figures on one track in detail (§5.5: Figs. 16, 17a–c, 12–13, 18), then the run details.
Nothing is recomputed but plotting percentiles and the single track's CIs over realizations.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from pipeline.infra.progress import bar as progress_bar

from pipeline.evaluation.metrics.spec import MGR_AXIS_LABEL
from pipeline.infra.outputs import path as out_path
from reports.main import calibration as calibration_sections
from reports.main import findings
from reports.main import instances as instance_sections
from reports.main import planning as planning_sections
from reports.main import power as power_sections
from reports.main import provided as provided_sections
from reports.main.calibration import CALIBRATED
from reports.main import track as track_sections
from reports.main import verdict as verdict_sections
from reports.main.contrast import contrast_section
from reports.main.showcase import showcase_section
from reports.main.uncertainty_source import uncertainty_source_section
from reports.main.reviewer import limitations_section, methods_section, reproduce_section, seeds_section
from reports.shared.artifacts import load_run
from reports.main.context import ReportContext
from reports.shared.checks import ReportCheckError
from reports.main.figure_pool import draw_one, draw_parallel, pool_size
from reports.main.figures_calibration import calibration_plan
from reports.main.figures_models import fig_bias_maps, fig_gp_rasters, fig_gp_ring
from reports.main.figures_results import (fig_bands, fig_biased, fig_forest, fig_per_target, fig_sensitivity,
                                     fig_track)
from reports.main.figures_models import bias_map_findings
from reports.main.figures_results import (decisive_step)
from reports.main.glossary import glossary_section
from reports.shared.html import HtmlReport
from reports.shared.stats import BOOTSTRAP, metric_params, track_summary
from reports.shared.tables import component_labels
from reports.main.bottom_line import counts, tracks_text

log = logging.getLogger("viewfuse.report")

SECTIONS = (verdict_sections.verdict_section, methods_section, limitations_section, seeds_section,
            calibration_sections.calibration_section, verdict_sections.population_section,
            power_sections.power_section, contrast_section,
            verdict_sections.diagnostics_section, calibration_sections.domain_section, uncertainty_source_section,
            calibration_sections.attribution_section, provided_sections.sections,
            instance_sections.instance_attribution_section, instance_sections.category_section,
            planning_sections.planning_section, showcase_section,
            track_sections.track_section, track_sections.randomized_section,
            track_sections.sensitivity_section, track_sections.bias_maps_section, track_sections.gp_section,
            glossary_section, reproduce_section, track_sections.details_section)


@dataclass
class ReportResult:
    index: Path
    figures: list[str]
    sections: list[str]
    notes: list[str]
    layout_problems: dict[str, list[str]] = field(default_factory=dict)   # figure -> slips kept on the page


STRICT_MODES = ("contradictions", "all")


def strict_mode(strict: str | bool) -> str:
    """``report.strict`` as a mode: 'all' (every self-check stops the build), 'contradictions'
    (a layout slip is shown on the page, not fatal) or 'none' (``False``: a look at a broken page)."""
    if strict is True or strict is False:
        return "all" if strict else "none"
    if strict not in STRICT_MODES:
        raise ValueError(f"report.strict: {strict!r} is not one of {', '.join(STRICT_MODES)}")
    return str(strict)


def _population_plan(ctx: ReportContext) -> list[tuple[str, Callable[[], Any]]]:
    pop = ctx.population
    if not pop:
        return []
    plan = []
    if pop.get("paired_per_target") or pop.get("paired"):
        plan.append(("forest.png", lambda: fig_forest(pop)))
        ctx.alts["forest.png"] = findings.forest(pop, ctx.ledger)
    if pop.get("per_target"):
        plan.append(("per_target.png", lambda: fig_per_target(pop)))
        ctx.alts["per_target.png"] = findings.per_target(pop, ctx.ledger)
    cal = calibration_plan(pop, ctx.ev.results)
    names = {n for n, _ in cal}
    if "reliability.png" in names:
        ctx.alts["reliability.png"] = findings.reliability(pop)
    if "reliability_calibrated.png" in names:
        ctx.alts["reliability_calibrated.png"] = findings.reliability(
            (pop.get("ablations") or {}).get(CALIBRATED) or {})
    if "pit.png" in names:
        ctx.alts["pit.png"] = findings.pit(pop.get("domain_fit") or {})
    return plan + cal


def _track_plan(ctx: ReportContext, clipped: dict[str, int]) -> list[tuple[str, Callable[[], Any]]]:
    ev, track = ctx.ev, ctx.ev.track or {}
    plan = []
    biased = ev.single_track("biased")
    if biased is not None:
        images = [str(x) for x in track.get("images") or []]
        plan.append(("biased_ptruth.png", lambda: fig_biased(biased, len(ev.classes), images)))
        ctx.alts["biased_ptruth.png"] = findings.biased(biased, decisive_step(biased))
    if track.get("camera_xy"):
        biases = sorted({(float(x), float(y)) for x, y in zip(biased["bias_x"], biased["bias_y"])}) \
            if biased is not None else []
        plan.append(("track.png", lambda: fig_track(track, biases)))
        ctx.alts["track.png"] = findings.track(track, biases)
    rnd = ev.single_track("randomized")
    for i, s in enumerate(ctx.track_summaries.get("randomized") or {}):
        sub = rnd[rnd["setting"] == s]
        plan.append((f"randomized_ptruth_{i}.png", lambda sub=sub, s=s: fig_bands(
            sub, "p_truth", "P(ground-truth class)", f"P(truth) per step, percentiles 10–90 % ({s})")[0]))
        plan.append((f"randomized_logmgr_{i}.png", lambda sub=sub, s=s, i=i: _logmgr_bands(sub, s, i, clipped)))
        ctx.alts[f"randomized_ptruth_{i}.png"] = findings.bands(sub, "p_truth")
        ctx.alts[f"randomized_logmgr_{i}.png"] = findings.bands(sub, "log10_mgr")
    if ctx.track_summaries.get("sensitivity"):
        plan.append(("sensitivity.png", lambda: fig_sensitivity(ctx.track_summaries["sensitivity"])))
        ctx.alts["sensitivity.png"] = findings.sensitivity(ctx.track_summaries["sensitivity"])
    return plan


def _logmgr_bands(sub, setting: str, i: int, clipped: dict[str, int]) -> Any:
    fig, n = fig_bands(sub, "log10_mgr", MGR_AXIS_LABEL, f"log10 MGR per step, percentiles 10–90 % ({setting})")
    clipped[f"randomized_logmgr_{i}.png"] = n
    return fig


def _models_plan(ctx: ReportContext) -> list[tuple[str, Callable[[], Any]]]:
    ev, track = ctx.ev, ctx.ev.track or {}
    plan = []
    if ev.gp is not None:
        gp_classes = [str(c) for c in ev.gp["classes"]] if "classes" in ev.gp else ev.classes
        inputs = track.get("gp_inputs")
        plan.append(("gp_rasters.png", lambda: fig_gp_rasters(ev.gp, gp_classes, ctx.comp_names, inputs)))
        plan.append(("gp_ring.png", lambda: fig_gp_ring(ev.gp, gp_classes, ctx.comp_names, inputs)))
        ctx.alts["gp_rasters.png"] = ctx.alts["gp_ring.png"] = findings.gp(ev.gp, ctx.comp_names)
    if ev.bias_maps is not None:
        images = [str(x) for x in ev.bias_maps.get("images", track.get("images") or [])]
        bm_classes = [str(c) for c in ev.bias_maps["classes"]] if "classes" in ev.bias_maps else ev.classes
        plan.append(("bias_maps.png", lambda: fig_bias_maps(ev.bias_maps, bm_classes, ev.target, images)))
        ctx.bias_findings = bias_map_findings(ev.bias_maps, bm_classes, ev.target)
        ctx.alts["bias_maps.png"] = findings.bias_maps(ctx.bias_findings)
    return plan


def _summaries(ctx: ReportContext, seed: int) -> None:
    for exp in ("biased", "randomized", "sensitivity"):
        d = ctx.ev.single_track(exp)
        if d is not None:
            ctx.track_summaries[exp] = track_summary(d, metric_params(ctx.population or {}, ctx.config),
                                                     n_boot=ctx.n_boot, seed=seed)


def _scans(pop: dict, track: dict) -> str:
    """The scans the evaluation drew tracks from (the population's, else the single track's)."""
    scans = sorted({t["scan"] for t in (pop or {}).get("tracks") or [] if isinstance(t, dict) and t.get("scan")})
    if not scans and track.get("scan"):
        scans = [track["scan"]]
    return f"scan{'s' if len(scans) > 1 else ''} {', '.join(scans)}" if scans else ""


def _subtitle(ctx: ReportContext) -> str:
    pop, track = ctx.population, ctx.ev.track or {}
    if pop:
        c = counts(pop)
        size = (f"{c['n_targets']} targets · {tracks_text(c)} · {c['n_settings']} settings"
                + (f" · {c['n_cells']} cells" if c.get("n_cells") else ""))
    parts = [f"run {ctx.run_name}" if ctx.run_name else "", size if pop else "one target, one track",
             _scans(pop, track)]
    return " · ".join(p for p in parts if p)


def _context(run_dir: str | Path, *, title: str, run_name: str, config: dict | None, timings: dict[str, float] | None,
             n_boot: int, seed: int, commit: str, config_file: str) -> ReportContext:
    ctx = ReportContext(HtmlReport(title), load_run(run_dir), run_name, config or {}, timings or {}, n_boot=n_boot,
                        commit=commit, config_file=config_file)
    ctx.comp_names = component_labels(ctx.run.index, ctx.run.evaluate.gp, ctx.run.evaluate.target)
    _summaries(ctx, seed)
    return ctx


def _figure_plan(ctx: ReportContext) -> list[tuple[str, Callable[[], Any]]]:
    return (_population_plan(ctx) + planning_sections.planning_plan(ctx) + _track_plan(ctx, ctx.clipped)
            + _models_plan(ctx))


def build_main_report(run_dir: str | Path, out_dir: str | Path, *, title: str = "viewfuse report", dpi: int = 110,
                      run_name: str = "", config: dict | None = None, timings: dict[str, float] | None = None,
                      progress: bool = True, n_boot: int = BOOTSTRAP, seed: int = 0, commit: str = "",
                      config_file: str = "", strict: str | bool = "all", workers: int | None = 1) -> ReportResult:
    """Render ``out_dir/index.html`` and its PNGs from ``run_dir``'s evaluate, models and classifier outputs.

    Self-checks come in two classes (``strict``, the config's ``report.strict``): contradictions (a
    label its CI contradicts, two numbers for one statistic, a value outside its CI, a caption
    without a finding) always stop the build; layout slips (figure text that overlaps or leaves
    the canvas after ``reports.shared.layout.finish_figure``) stop it under 'all' only, and under
    'contradictions' the page is written with a warning box on the figure and a logged warning.

    ``workers``: processes that draw the figures (1: in this process, the default: a library call
    starts no processes unless asked; ``None``: the free cores, ``reports.main.figure_pool``, as the
    report stage asks); the files are the same either way."""
    mode = strict_mode(strict)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ctx = _context(run_dir, title=title, run_name=run_name, config=config, timings=timings, n_boot=n_boot, seed=seed,
                   commit=commit, config_file=config_file)
    plan = _figure_plan(ctx)
    # the figures to draw (a test narrows the plan through progress_bar: tests/support/report_fixtures.py)
    plan = list(progress_bar(plan, enabled=False))
    n = pool_size(len(plan), workers)
    if n > 1:
        drawn = draw_parallel(plan, out, dpi, n, ctx.clipped, progress)
    else:
        drawn = [draw_one(name, build, out, dpi, ctx.clipped)
                 for name, build in progress_bar(plan, desc="report figures", unit="fig", enabled=progress)]
    written = []
    for name, chk, clipped in drawn:
        ctx.checks[name] = chk
        if clipped is not None:
            ctx.clipped[name] = clipped
        slips = list(chk.text_problems)   # the self-check's figure_text_problems, from save's one placement
        if slips:
            ctx.layout_problems[name] = slips
        written.append(name)
        if chk.overlaps:
            ctx.notes.append(f"{name}: tick labels overlap ({'; '.join(chk.overlaps[:3])})")
    ctx.figures = set(written)
    ctx.page.subtitle = _subtitle(ctx)
    if ctx.source.badge:
        ctx.page.badge = ctx.source.badge
    for section in SECTIONS:
        section(ctx)
    for n in ctx.notes:
        log.warning("report: %s", n)
    layout = [p for slips in ctx.layout_problems.values() for p in slips]
    contradictions = ctx.problems + ctx.ledger.problems()
    fatal = contradictions + (layout if mode == "all" else [])
    if fatal and mode != "none":
        # Nothing is published that contradicts itself: index.html is not written.
        raise ReportCheckError(fatal)
    for name, slips in ctx.layout_problems.items():
        # a layout slip is not a contradiction: the figure carries a warning box (ctx.figure)
        log.warning("report: %s: figure text still overlaps or leaves the canvas after layout (%d problem%s; "
                    "shown on the page): %s", name, len(slips), "s" if len(slips) != 1 else "", "; ".join(slips[:3]))
    for p in contradictions if mode == "none" else []:  # a look at a broken page: every problem on it
        log.warning("report self-check: %s", p)
        ctx.page.paragraph(f"Self-check failed: {p}", cls="warn")
    ctx.page.write(out_path(out, "report", "html"))
    return ReportResult(out_path(out, "report", "html"), written, ctx.sections, ctx.notes,
                        dict(ctx.layout_problems))
