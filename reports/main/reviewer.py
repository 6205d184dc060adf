"""What a reviewer asks after the verdict, each answered from the run itself: what every method
does, the limits of this evaluation (computed from the config and summary.json, never a fixed
list), how much the verdict moves with the classifier's training seed, and how to reproduce the
page (command, commit, the config's differences from the defaults, the JSON files behind it)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pipeline.evaluation.metrics.labels import method_label, method_note, ordered_methods
from pipeline.infra.outputs import path as out_path
from pipeline.infra.outputs import read as read_artifact
from reports.main.bottom_line import counts
from reports.main.context import ReportContext
from reports.shared.figures import MGR_SATURATION
from reports.shared.numbers import plain
from reports.shared.records import varies_text
from pipeline.infra.config import Config, to_dict

def data_extra(ctx: ReportContext) -> dict:
    """The data stage manifest's extras (what the real-imagery writer measured), or {}."""
    return (((getattr(ctx.run, "manifests", None) or {}).get("data") or {}).get("extra") or {})


def box_fit_text(ctx: ReportContext) -> str | None:
    """How far the uniform fit leaves each object from filling its real box, or None."""
    bf = data_extra(ctx).get("box_fit")
    if not isinstance(bf, dict) or not bf.get("frames"):
        return None
    fill, scale = bf.get("fill") or {}, bf.get("scale") or {}
    return (f"Each object is scaled uniformly into the real AVD box of its frame (never stretched; the box written "
            f"for the classifier is the object's own, centred in the real one): over {bf['frames']} frames the "
            f"object box covers a median {fill.get('median')} of the real box's area (5th-95th percentile "
            f"{fill.get('p5')}-{fill.get('p95')}; below half in {round(100 * float(bf.get('share_fill_below_0_5', 0)))} "
            f"% of frames) at a median scale of {scale.get('median')} frame pixels per photograph pixel "
            f"({scale.get('p5')}-{scale.get('p95')}).")


def methods_section(ctx: ReportContext) -> None:
    pop = ctx.population or {}
    methods = ordered_methods(pop.get("methods") or [])
    if not methods:
        return
    ctx.section("The methods compared", "methods")
    ctx.page.table(["method", "what it does"], [[method_label(m), method_note(m)]
                                                for m in methods], cls="methods")


def limitations(ctx: ReportContext) -> list[str]:
    """The limits of this run's evidence, each read off the config or summary.json."""
    pop, ev_cfg = ctx.population or {}, (ctx.config.get("evaluate") or {})
    out = []
    src = ev_cfg.get("yaw_source")
    if src == "truth":
        out.append("The object's yaw (which way it faces) comes from the ground truth of the synthetic data, not "
                   "from an estimate: the viewpoint each GP is read at is exact up to the camera pose.")
    elif src == "config":
        out.append("The object's yaw comes from the configuration (one fixed value per target), not from an "
                   "estimate.")
    scans = sorted({str(t.get("scan")) for t in pop.get("tracks") or [] if isinstance(t, dict) and t.get("scan")})
    tdv = ((pop.get("domain_fit") or {}).get("test_domain_variance") or {})
    if tdv:
        n_folds = len(tdv.get("per_fold") or {})
        by = "scans" if tdv.get("folds_by") == "scan" else "objects"
        out.append(f"The calibrated likelihood's extra variance is estimated with cross-fitting over {n_folds} "
                   f"{by}" + (f" ({', '.join(scans)})" if by == "scans" and scans else "")
                   + ": each fold's estimate rests on the others alone, so with few folds it is coarse.")
    if pop:
        c = counts(pop)
        single = c["single_track_targets"]
        if single:
            one = len(single) == 1
            out.append(f"{len(single)} of {c['n_targets']} targets {'has' if one else 'have'} a single track "
                       f"({', '.join(single)}): {'it has' if one else 'they have'} no interval of "
                       f"{'its' if one else 'their'} own and {'weighs' if one else 'weigh'} on the pooled value like "
                       "the others.")
        out.append(evidence_text(pop, c["n_targets"], scans))
    gone = [s for s in pop.get("skipped_targets") or [] if isinstance(s, dict) and not s.get("scan")]
    if gone:
        out.append(f"{len(gone)} target{'s were' if len(gone) != 1 else ' was'} skipped for want of a usable track "
                   f"and {'are' if len(gone) != 1 else 'is'} not in the population: "
                   + "; ".join(f"{s.get('target')} ({s.get('reason')})" for s in gone))
    ve = (((ctx.run.manifests or {}).get("data") or {}).get("extra") or {}).get("view_error_deg") \
        if getattr(ctx.run, "manifests", None) else None
    if isinstance(ve, dict) and ve.get("frames"):
        out.append(f"Each frame shows the held-out photograph nearest the camera's bearing, not the bearing itself: "
                   f"over {ve['frames']} candidate frames the viewpoint error has median {ve.get('median')}°, "
                   f"90th percentile {ve.get('p90')}°, maximum {ve.get('max')}°; {ve.get('refused', 0)} beyond "
                   f"data.{ctx.data_source}.max_view_error_deg = {ve.get('bound')}° got no frame.")
    fit = box_fit_text(ctx)
    if fit:
        out.append(fit)
    seeds = (ctx.config.get("study") or {}).get("seeds") or []
    train = ((ctx.run.card or {}).get("training") or {}).get("seed")
    if not _study(ctx):
        out.append(f"One classifier training run (seed {train if train is not None else 'unknown'}): the intervals "
                   "do not cover what another training run would change (see the seed section below).")
    elif seeds:
        out.append(f"Classifier training varies over {len(seeds) + 1} seeds in the seed study only; every other "
                   "number on this page comes from one of them.")
    sat = saturated(pop)
    if sat:
        out.append(f"{len(sat)} (target, method) pairs reach a log10 MGR above {plain(MGR_SATURATION)} "
                   f"({', '.join(sat[:6])}{', …' if len(sat) > 6 else ''}): numerical saturation (see the "
                   "glossary), so means of log10 MGR are dominated by them; the pooled log10 MGR is a median over "
                   "targets for that reason.")
    if ctx.source.rendered:
        out.append("The images are synthetic stand-ins rendered in the datasets' formats, not the real BigBIRD "
                   "and AVD photographs, so the paper's numbers are not expected to be reproduced.")
    return out


def saturated(pop: dict) -> list[str]:
    """'target / method' of every per-target or pooled log10 MGR value above the saturation cap."""
    out = []
    for t, per in (pop.get("per_target") or {}).items():
        for m, d in (per or {}).items():
            for k, e in (d or {}).items():
                v = (e or {}).get("value") if isinstance(e, dict) else None
                if k.startswith("log10_mgr") and v is not None and float(v) > MGR_SATURATION:
                    out.append(f"{t} / {method_label(m, short=True)}")
    return sorted(set(out))


def limitations_section(ctx: ReportContext) -> None:
    items = limitations(ctx)
    if not items:
        return
    ctx.section("Limitations of this run", "limitations")
    for item in items:  # paragraphs, not a list: the page's lists are its verdict sentences
        ctx.page.paragraph(item, cls="limitation")


def _study(ctx: ReportContext) -> dict | None:
    try:
        return read_artifact(Path(ctx.run.run_dir) / "study", "study", "summary", missing=None)
    except (OSError, ValueError):
        return None


def seeds_section(ctx: ReportContext) -> None:
    """Seed variability where a seed study ran in this run folder; a visible note where not."""
    ctx.section("Classifier seed variability", "seeds")
    st = _study(ctx)
    if st is None:
        ctx.page.paragraph("No seed study in this run folder: every interval on this page varies over targets and "
                           "tracks only, with one classifier training run. The seed study retrains the classifier "
                           "with other seeds and says whether each verdict stays the same "
                           "(the command viewfuse study; its page is study/index.html).", cls="warn")
        return
    seeds = st.get("seeds") or []
    same = st.get("same_verdict")
    ctx.page.paragraph(f'A seed study ran over {len(seeds)} classifier seeds; '
                       + ("every verdict is the same for every seed. " if same is True else
                          "some verdicts change with the seed. " if same is False else "")
                       + 'Its page: <a href="../study/index.html">seed study</a>.', html=True)


def config_diff(config: dict) -> list[list[str]]:
    """(key, default, this run) for every key this run sets differently from the defaults."""
    default = to_dict(Config())
    rows: list[list[str]] = []
    _diff(default, config, "", rows)
    return rows


def _diff(a: Any, b: Any, prefix: str, rows: list[list[str]]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in ("source_path", "path_roots"):
                continue
            _diff(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else k, rows)
    elif a != b and b is not None:
        rows.append([prefix, _show(a), _show(b)])


def _show(v: Any) -> str:
    return json.dumps(v, ensure_ascii=False) if not isinstance(v, str) else v


def reproduce_section(ctx: ReportContext) -> None:
    ctx.section("Reproduce this page", "reproduce")
    cfg_file = ctx.config_file or "<your config>.toml"
    commit = ctx.commit or "unknown"
    ctx.page.preformatted(f"git checkout {commit}\npython -m stages.commands.cli report --config {cfg_file}\n"
                          "# or the whole chain: make features models evaluate report",
                          caption="Commands (the stages rerun only what is out of date).")
    rows = config_diff(ctx.config) if ctx.config else []
    ctx.page.table(["setting", "default", "this run"], rows or [["—", "—", "every setting at its default"]],
                   cls="config-diff", caption="This run's configuration where it differs from the defaults.")
    run = Path(ctx.run.run_dir)
    files = [("verdicts, pooled values and intervals", out_path(run / "evaluate", "evaluate", "summary")),
             ("every cell's metrics", out_path(run / "evaluate", "evaluate", "results")),
             ("the GP fits", out_path(run / "models", "models", "index")),
             ("the classifier", out_path(run / "classifier", "classifier", "card"))]
    ctx.page.table(["what", "file (relative to the run folder)"],
                   [[w, str(p.relative_to(run))] for w, p in files if p.exists()], cls="json-paths",
                   caption="The files every number on this page is read from.")


def evidence_text(pop: dict, n_targets: int, scans: list[str]) -> str:
    """What the run's intervals vary over, from its design: where the engine withheld them (a level
    the design varies over with too few units: ``design.withheld``), which and why, never a claim
    that they vary."""
    where = f"The evidence covers {n_targets} targets in {len(scans) or '?'} scan{'s' if len(scans) != 1 else ''}"
    recs = [r for r in pop.get("records") or [] if isinstance(r, dict)]
    held = [r for r in recs if r.get("withheld")]
    if not held:
        return (f"{where}: the intervals vary over {varies_text(pop)} of these scans, not over other homes or "
                "other objects.")
    n = f"all {len(recs)}" if len(held) == len(recs) else f"{len(held)} of {len(recs)}"
    return (f"{where}: too few units for a calibrated interval ({held[0]['withheld']}), so {n} paired differences "
            "and the pooled values resting on the same design carry no CI and no verdict: their numbers are point "
            f"values of {'this scan' if len(scans) == 1 else 'these scans'} only, not evidence about other homes or "
            "other objects.")
