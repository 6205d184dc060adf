"""Alt text that states what each figure shows (its finding), computed from the same data as the
figure: a reader who cannot see the image learns the result, not the caption again."""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.metrics.labels import method_label, ordered_methods
from pipeline.evaluation.metrics.spec import higher_is_better, metric_label, percentile
from reports.main.calibration import pooled_value
from reports.shared.checks import Ledger
from reports.shared.numbers import Estimate, fmt, percent
from reports.shared.records import clause, find, records_of


def forest(pop: dict, ledger: Ledger | None = None) -> str:
    """The pooled paired differences the plot shows, each as its verdict record words it
    (``reports.shared.records.clause``), and how many targets' own CIs exclude 0."""
    recs, ppt = records_of(pop), pop.get("paired_per_target") or {}
    parts = []
    for key in pop.get("paired") or {}:
        for metric in ("correct_final", "log10_mgr95_final"):
            rec = find(recs, key, metric)
            if rec is None:
                continue
            if ledger is not None:
                ledger.register(("paired", key, metric), rec.get("value"), rec.get("lo"), rec.get("hi"),
                                label="" if rec.get("withheld") else rec["outcome"], where="forest plot caption",
                                higher_is_better=higher_is_better(metric))
            excl = sum(1 for t in (ppt.get(key) or {}).values()
                       if Estimate.of((t or {}).get(metric)).excludes_zero())
            parts.append(f"{clause(rec)}; {excl} of {len(ppt.get(key) or {})} targets have a CI excluding 0")
    return "Forest plot of paired differences. " + "; ".join(parts) + "." if parts else "Forest plot of paired differences."


def per_target(pop: dict, ledger: Ledger | None = None) -> str:
    pooled, per = pop.get("pooled") or {}, pop.get("per_target") or {}
    methods = ordered_methods(pooled)
    out = []
    for metric in ("correct_final", "log10_mgr95_final"):
        # the statistic the verdict and the pooled table use (median over targets for unbounded metrics)
        ests = {m: pooled_value(pop, m, metric) for m in methods}
        if ledger is not None:
            for m, d in ests.items():
                ledger.register_estimate(("pooled", m, metric), d, where="per-target figure caption")
        vals = ", ".join(f"{method_label(m, True)} {Estimate.of(ests[m]).text()}" for m in methods)
        out.append(f"pooled {metric_label(metric)}: {vals}")
    worst = [(float(((per[t].get(m) or {}).get("log10_mgr95_final") or {}).get("value") or 0), t, m)
             for t in per for m in per[t]]
    if worst:
        v, t, m = max(worst)
        out.append(f"largest per-target log10 MGR95: {t} with {method_label(m, True)} ({fmt(v)})")
    return "Per-target values with CIs. " + "; ".join(out) + "."


def biased(df, key: dict | None) -> str:
    fin = df[df["step"] == df["step"].max()].groupby("method")["p_truth"].median()
    vals = ", ".join(f"{method_label(m, True)} {fmt(fin[m])}" for m in ordered_methods(fin.index))
    moved = (f"; view {key['step']} moves P(truth) most ({method_label(key['method'], True)}: "
             f"{fmt(key['before'])} → {fmt(key['after'])})" if key else "")
    return f"P(truth) along the biased showcase track; final step: {vals}{moved}."


def bands(df, column: str) -> str:
    fin = df[df["step"] == df["step"].max()]
    parts, meds = [], []
    for m in ordered_methods(fin["method"].unique()):
        v = fin[fin["method"] == m][column].to_numpy(float)
        lo, med, hi = percentile(v, [10, 50, 90])
        parts.append(f"{method_label(m, True)} median {fmt(med)} (10–90 %: {fmt(lo)} to {fmt(hi)})")
        meds.append((float(med), method_label(m, True)))
    what = "P(truth)" if column == "p_truth" else "log10 MGR"
    # the finding: which method ends best (highest P(truth), lowest log10 MGR)
    best = (max(meds) if column == "p_truth" else min(meds)) if meds else None
    lead = (f"; the {'highest' if column == 'p_truth' else 'lowest'} median is {best[1]}'s"
            if best is not None and len({v for v, _ in meds}) > 1 else "; every method ends at the same median"
            if meds else "")
    return f"{what} at the final step over realizations: " + "; ".join(parts) + lead + "."


def sensitivity(summ: dict) -> str:
    settings = sorted(summ, key=lambda s: summ[s]["sigma_m"])
    if not settings:
        return "σ sweep."
    a, b = settings[0], settings[-1]
    parts = []
    for m in ordered_methods({m for s in settings for m in summ[s]["methods"]}):
        e0, e1 = (summ[s]["methods"].get(m, {}).get("correct_final") for s in (a, b))
        if e0 is not None and e1 is not None:
            parts.append(f"{method_label(m, True)} {fmt(e0.value)} → {fmt(e1.value)}")
    return (f"Correct ratio at the final step from σ = {fmt(summ[a]['sigma_m'])} m to σ = {fmt(summ[b]['sigma_m'])} m: "
            + ", ".join(parts) + ".")


def bias_maps(found: dict) -> str:
    views = found["views"]
    n0 = found["n_truth_at_zero"]
    flips = [v for v in views if v["flip_radius_m"] is not None]
    near = min(flips, key=lambda v: v["flip_radius_m"]) if flips else None
    lost = [v for v in views if not v["truth_at_zero"]]
    out = [f"The truth class {found['truth']} wins at zero bias in {n0} of {found['n_views']} views"]
    if near is not None:
        out.append(f"the smallest bias that flips a correct view is {fmt(near['flip_radius_m'])} m (view {near['view']})")
    if lost:
        out.append("views where another class wins already at zero bias: "
                   + ", ".join(f"{v['view']} ({v['winner_at_zero']})" for v in lost[:6]))
    return "; ".join(out) + "."


def bias_caption(found: dict) -> str:
    """The section's claim, from the maps themselves (it must not say 'a small error flips the
    decision' where the truth loses everywhere)."""
    flips = [v for v in found["views"] if v["flip_radius_m"] is not None]
    lost = [v for v in found["views"] if not v["truth_at_zero"]]
    s = f"In {found['n_truth_at_zero']} of {found['n_views']} views the truth class wins at zero bias"
    if flips:
        r = min(v["flip_radius_m"] for v in flips)
        s += f"; there a bias of {fmt(r)} m or more can flip the decision (paper Fig. 18)"
    if lost:
        s += f"; in {len(lost)} view{'s' if len(lost) != 1 else ''} another class wins even at zero bias, so no localization error is needed"
    return s + "."


def gp(gpd: dict, comp_names: list[str]) -> str:
    rm = np.asarray(gpd["ring_mean"], float)   # (C, F, T)
    C, F = rm.shape[:2]
    spread = np.nanmean(np.nanmax(rm, 0) - np.nanmin(rm, 0), axis=-1)   # per component
    f = int(np.nanargmax(spread)) if F else 0
    name = comp_names[f] if f < len(comp_names) else f"component {f}"
    return (f"GP means of {C} classes on {F} score components; the component that separates the classes most along "
            f"the ring is {name} (mean gap between the highest and lowest class {fmt(spread[f])}).")


def track(track: dict, biases: list) -> str:
    cam = np.asarray(track.get("camera_xy") or [], float).reshape(-1, 2)
    est = track.get("object_xy_est")
    tru = track.get("object_xy_truth")
    out = [f"The track: {len(cam)} camera positions"]
    if est is not None and len(cam):
        d = np.hypot(*(cam - np.asarray(est, float)).T)
        out.append(f"{fmt(d.min())}–{fmt(d.max())} m from the estimated object")
    if est is not None and tru is not None:
        out.append(f"object estimate {fmt(100 * float(np.hypot(est[0] - tru[0], est[1] - tru[1])))} cm from the truth")
    if biases:
        out.append("biased estimates shifted by " + ", ".join(f"({fmt(b[0])}, {fmt(b[1])}) m" for b in biases[:3]))
    return "; ".join(out) + "."


def reliability(block: dict, where: str = "final") -> str:
    """Each method's ECE (pooled posteriors) and which is best calibrated."""
    pooled = block.get("pooled") or {}
    eces = [(float(e["value"]), m) for m in ordered_methods((block.get("reliability") or {}).keys())
            for e in [((pooled.get(m) or {}).get(f"ece_{where}") or {})] if e.get("value") is not None]
    if not eces:
        return "Reliability diagram (no ECE recorded)."
    parts = ", ".join(f"{method_label(m, True)} {fmt(v)}" for v, m in eces)
    best = min(eces)
    return (f"ECE ({where} step): {parts}; the lowest (best calibrated) is {method_label(best[1], True)}'s; "
            "points below the diagonal are overconfident bins.")


def pit(domain: dict) -> str:
    """Per variance model: share of |z| > 3 (3e-3 when the model fits) and which is closest to flat."""
    from reports.main.figures_calibration import KIND_TITLES  # heavy: matplotlib
    rows = [(float(o.get("share_gt3") or 0), k) for k in ("gp", "gp_plus_dropout", "gp_calibrated")
            for o in [((domain.get(k) or {}).get("overall") or {})] if o]
    if not rows:
        return "PIT histograms (no residuals recorded)."
    parts = "; ".join(f"{KIND_TITLES.get(k, k)}: {percent(v, 1)} of |z| above 3" for v, k in rows)
    best = min(rows)
    return (f"{parts} (0.3 % if the model fitted); the fewest outliers with {KIND_TITLES.get(best[1], best[1])}.")
