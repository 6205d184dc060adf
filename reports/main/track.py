"""The detailed-track sections (the paper's §5.5 figures on the first target's first track), the GP
models and the run details. CIs here resample realizations, so they cover localization noise only;
the captions say so."""
from __future__ import annotations

import math

from pipeline.evaluation.metrics.labels import method_label
from pipeline.evaluation.metrics.spec import MGR_AXIS_LABEL, metric_label
from reports.main.context import ReportContext
from reports.shared.numbers import Estimate, fmt, plain
from reports.shared.tables import (component_legend, dump_toml, find_seeds, package_versions, skip_rows)

TRACK_TABLE = ("correct_final", "correct_overall", "log10_mgr95_final", "log10_mgr95_overall")


def track_table(ctx: ReportContext, experiment: str, caption: str) -> None:
    summ = ctx.track_summaries.get(experiment) or {}
    rows = []
    for setting, cell in summ.items():
        for m, est in cell["methods"].items():
            # One realization has no spread to resample: its values stand alone.
            vals = [est[k] if cell["n_realizations"] > 1 else Estimate(est[k].value) for k in TRACK_TABLE]
            rows.append([setting, method_label(m, short=True)] + vals
                        + [cell["n_realizations"]])
    if not rows:
        return
    many = any(c["n_realizations"] > 1 for c in summ.values())
    caption += (f" Value [95 % CI]; CIs: bootstrap ({ctx.n_boot} resamples, seeded) over realizations, so they "
                "cover the localization noise only." if many else " One realization: no CI.")
    ctx.page.table(["setting", "method"] + [metric_label(k, short=True) for k in TRACK_TABLE] + ["realizations"],
                   rows, cls=f"summary {experiment}", caption=caption)


def track_section(ctx: ReportContext) -> None:
    ev, track = ctx.ev, ctx.ev.track or {}
    biased = ev.single_track("biased")
    if not track and biased is None:
        return
    ctx.section("One track in detail", "track")
    K = len(track.get("images") or [])
    where = (f"target {ev.target or '?'}" + (f", track {ev.track_id}" if ev.track_id is not None else "")
             + (f" in scan {track['scan']}" if track.get("scan") else ""))
    show = (ctx.population or {}).get("showcase") or {}
    why = (f"chosen by a recorded rule: {show.get('rule')}; here the methods' "
           f"final correct ratios differ by {fmt(show.get('correct_spread'))} on average over the settings "
           f"(of {show.get('candidates')} tracks{', ' + str(show.get('ties')) + ' tied' if show.get('ties') else ''})"
           if show.get("rule") else "the population's first target and track")
    ctx.page.paragraph(
        f"The paper's figures for one track ({where}, {K} views), {why}. Candidates: {', '.join(ev.classes) or '—'}. "
        "Spread here comes from localization noise alone, not from other tracks or objects.")
    if biased is not None:
        b = sorted({(float(x), float(y)) for x, y in zip(biased["bias_x"], biased["bias_y"])})
        sig = ", ".join(fmt(v) for v in sorted(set(biased["sigma_m"])))
        ctx.page.paragraph(
            "Biased track: every pose estimate is shifted by " + ", ".join(f"({plain(x, signed=True)}, {plain(y, signed=True)}) m" for x, y in b)
            + f". Model Based uses the shifted estimates as if exact; With Uncertainty also knows the localization "
              f"noise σ = {sig} m and averages over sampled poses.")
    ctx.figure("track.png", "Track seen from above: camera positions (numbered in track order) with headings, "
                            "the object estimate and truth, and the biased pose estimates (hollow).")
    if biased is not None:
        ctx.figure("biased_ptruth.png", "P(ground-truth class) per step along the biased track (paper Fig. 17a). "
                                        "Dashed: uniform prior; shaded: the view that moves P(truth) most.")
        track_table(ctx, "biased", "Biased track.")


def randomized_section(ctx: ReportContext) -> None:
    summ = ctx.track_summaries.get("randomized")
    if not summ:
        return
    ctx.section("Randomized localization error (one track)", "randomized")
    ctx.page.paragraph("Each realization draws pose estimates = truth + bias + N(0, σ²I) per view; bands show the "
                       "10–90 % percentiles over realizations in 10 % steps, the median darkest, drawn as steps "
                       "because the track is observed at discrete steps (paper Fig. 17b–c).")
    for i, s in enumerate(summ):
        ctx.figure(f"randomized_ptruth_{i}.png", f"P(ground-truth class) per step, {s}.")
        ctx.figure(f"randomized_logmgr_{i}.png", f"{MGR_AXIS_LABEL} per step, {s} (0: the truth is the most "
                                                  "likely class; higher: more confidently wrong).")
    for key, n in ctx.clipped.items():
        if n:
            note = f"{key}: {n} infinite value{'s' if n != 1 else ''} (truth probability 0) drawn at the top of the axis."
            ctx.notes.append(note)
            ctx.page.paragraph(note, cls="warn")
    track_table(ctx, "randomized", "Randomized experiment on this track (paper Tables 1–2).")


def sensitivity_section(ctx: ReportContext) -> None:
    if not ctx.track_summaries.get("sensitivity"):
        return
    ctx.section("Sensitivity to σ (one track)", "sensitivity")
    ctx.page.paragraph("The randomized experiment repeated over a sweep of localization noise σ on the detailed "
                       "track (paper Figs. 12–13), with 95 % CIs over realizations.")
    ctx.figure("sensitivity.png", "Left: correct ratio at the final step. Right: 95th percentile of log10 MGR at "
                                  "the final step (symlog axis: linear in [−1, 1]; 0 = truth most likely). Bars: 95 % "
                                  "bootstrap CIs.")
    track_table(ctx, "sensitivity", "σ sweep, per σ and method.")


def bias_maps_section(ctx: ReportContext) -> None:
    if "bias_maps.png" not in ctx.figures:
        return
    ctx.section("Bias maps (one track)", "bias-maps")
    from reports.main.findings import bias_caption  # heavy: pandas
    ctx.page.paragraph("For each view of the detailed track alone, the Model Based class posterior when its pose "
                       "estimate is off by a 2D bias (x, y): the hue and the letter give the most probable class "
                       "(black lines separate the classes, so the map also reads in greyscale), the brightness that "
                       "class's probability (dark = near uniform; the colour scale is under the maps). "
                       + (bias_caption(ctx.bias_findings) if ctx.bias_findings else ""))
    ctx.figure("bias_maps.png", "Single-view Model Based posterior over a grid of pose biases; '+' marks zero "
                                "bias, the white outline the region where the truth class wins; each title gives the "
                                "share of the grid where it wins.")


def gp_section(ctx: ReportContext) -> None:
    if "gp_rasters.png" not in ctx.figures:
        return
    ctx.section("GP class models", "gp")
    names = ctx.comp_names
    example = (names[0].rsplit(" (score ", 1)[0], int(names[0].rsplit(" ", 1)[-1].rstrip(")"))) \
        if names and "(score " in names[0] else ("chevron", 4)
    ctx.page.paragraph("Each candidate class has one GP per chosen score component, a function of the viewing "
                       "direction (unit-circle input). Dots on the ring are the training views (BigBIRD turntable), "
                       "coloured by their score on the same scale; red crosses are the track's views.")
    ctx.page.paragraph(component_legend(ctx.run.card, example), cls="note")
    ctx.figure("gp_rasters.png", "GP mean per class × component over the unit square, with the training ring "
                                 "(paper Fig. 16); one colour scale per component.")
    ctx.figure("gp_ring.png", "GP mean ± 2σ along the training ring vs viewing angle, one panel per component, "
                              "classes in colour; dots are training scores.")


def details_section(ctx: ReportContext) -> None:
    ctx.section("Run details", "details")
    page = ctx.page
    page.table(["", ""], _facts(ctx), cls="facts")
    skips = skip_rows(ctx.run.skipped())
    skips += [["evaluate", f"target {s.get('target')}", 1, s.get("reason") or "—"]
              for s in (ctx.population or {}).get("skipped_targets") or []]
    page.table(["stage", "what", "skipped", "reasons"], skips or [["—", "no stage recorded skips", 0, "—"]],
               caption="Skipped inputs, from each stage's manifest (extra.skipped).")
    seeds = dict(find_seeds(ctx.config))
    seeds.update({f"evaluate output: {k}": v for k, v in ((ctx.ev.summary or {}).get("seeds") or {}).items()})
    if "seed" in ctx.ev.meta:
        seeds["results.parquet metadata"] = ctx.ev.meta["seed"]
    if seeds:
        page.table(["seed", "value"], [[k, str(v)] for k, v in seeds.items()], caption="Seeds.")
    t_rows = [[k, v] for k, v in ctx.timings.items()]
    t_rows += [["data … evaluate (whole chain)" if k == "chain_total" else f"evaluate: {k}", v]
               for k, v in ((ctx.ev.summary or {}).get("timings_s") or {}).items()]
    if t_rows:
        page.table(["stage / part", "seconds"], t_rows, caption="Timings.")
    page.table(["package", "version"], [[k, v] for k, v in package_versions().items()], caption="Package versions.")
    if "config_hash" in ctx.ev.meta:
        page.paragraph(f"Config hash (results metadata): {ctx.ev.meta['config_hash']}", cls="note")
    if ctx.config:
        page.preformatted(dump_toml(ctx.config), caption="Resolved configuration.")


def _facts(ctx: ReportContext) -> list[list]:
    ev, track, index = ctx.ev, ctx.ev.track or {}, ctx.run.index or {}
    facts = [["run", ctx.run_name or "—"], ["data source", ctx.data_source],
             ["detailed track: target", ev.target or "—"], ["candidate classes", ", ".join(ev.classes) or "—"],
             ["scan", track.get("scan") or "—"]]
    if track.get("images"):
        facts.append(["track views", f"{len(track['images'])}: " + ", ".join(track["images"])])
    est, tru = track.get("object_xy_est"), track.get("object_xy_truth")
    if est is not None:
        facts.append(["object position estimate (m)", f"({fmt(est[0])}, {fmt(est[1])})"])
    if est is not None and tru is not None:
        err = math.hypot(est[0] - tru[0], est[1] - tru[1])
        facts.append(["object position error", f"{fmt(100 * err)} cm (ray intersection vs truth)"])
    elif track.get("localization_error_m") is not None:
        facts.append(["object position error", f"{fmt(100 * float(track['localization_error_m']))} cm"])
    if track.get("yaw_deg") is not None:
        facts.append(["object yaw", f"{fmt(float(track['yaw_deg']))}°"])
    if ctx.run.card:  # numbers move with the processor as with the seed: say which one trained and ran
        facts.append(["classifier's machine", machine_text(ctx.run.card.get("determinism"))])
        if ctx.run.card.get("weights_sha256"):
            facts.append(["classifier weights sha256", str(ctx.run.card["weights_sha256"])])
    rule = index.get("rule") or (index.get("component_choice") or {}).get("rule")
    if ctx.comp_names:
        facts.append(["GP components", ", ".join(ctx.comp_names) + (f" (rule: {rule})" if rule else "")])
    return facts


def machine_text(fp: dict | None) -> str:
    """The classifier card's machine (its ``determinism`` block) in one line for people:
    'AMD EPYC (torch CPU capability AVX2, 2 threads, torch 2.x, torch BLAS mkl)'."""
    if not fp:
        return "not recorded (a card written before the classifier stage recorded its machine)"
    blas = (fp.get("blas") or {}).get("torch_blas_info")
    ver = (fp.get("versions") or {}).get("torch")
    parts = [f"torch CPU capability {fp['cpu_capability']}" if fp.get("cpu_capability") else None,
             f"{fp['torch_threads']} threads" if fp.get("torch_threads") is not None else None,
             f"torch {ver}" if ver else None, f"torch BLAS {blas}" if blas else None]
    return f"{fp.get('cpu_model') or 'unknown processor'} ({', '.join(p for p in parts if p)})"
