"""The simulation report (paper §5.3): figures and page for the ``simulate`` stage.

Reads only what the stage wrote (``results.parquet``, ``example.parquet``, ``summary.json``,
``models/``, read by ``reports.shared.artifacts`` like the main report) and computes nothing but
percentiles, GP means for the maps and CIs over realizations (seeded bootstrap), so the page can be
re-rendered from the artifacts. Same conventions as the main report: names and colours from
``pipeline.evaluation.metrics.labels``, MGR as log10 on linear axes, every table value with its 95 % CI.

Figures: class maps (model points, track, biased estimates); the measurements over the track for
the example realization (paper Figs. 2 and 4); percentile bands over realizations per step of
P(truth), log10 MGR and MSDE, each method against With Uncertainty (paper Figs. 3 and 5); the
confident-error rate per step; the regime sweep of the paper's claims (``reports.simulate.claims``,
which also writes the claims table at the top of the page).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics.labels import (MODEL_BASED, SIMPLE_BAYES, class_colors, method_color,
                                                method_label, ordered_methods)
from pipeline.method.gp_files import load_bank
from pipeline.evaluation.metrics.spec import MGR_AXIS_LABEL, metric_label
from pipeline.infra.outputs import name as out_name
from pipeline.infra.outputs import path as out_path
from reports.shared.artifacts import load_simulate
from reports.shared.figures import new_subplots, percentile_bands, save
from reports.shared.html import HtmlReport
from reports.shared.numbers import MISSING, plain
from reports.simulate.claims import claims_section, fig_confident_errors, fig_sweep
from reports.simulate.findings import OURS, findings_text, matrix
from reports.shared.stats import BOOTSTRAP, metric_params, track_summary
from pipeline.method.registry import methods, model_providers
from pipeline.infra.progress import bar as progress_bar

log = logging.getLogger("viewfuse.simulate")

SCENARIO_TITLES = {
    "model_uncertainty": "Model uncertainty (Algorithm 2), exact poses",
    "localization_bias": "Localization bias, no model uncertainty",
}
TABLE = ("correct_final", "correct_overall", "log10_mgr95_final", "log10_mgr95_overall")


@dataclass
class ReportResult:
    index: Path
    figures: list[str] = field(default_factory=list)


# -- figures ----------------------------------------------------------------------------------------------
def _int_steps(ax) -> None:
    from matplotlib.ticker import MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _finite_cap(v: np.ndarray) -> np.ndarray:
    """+inf (a truth probability that underflowed) drawn at the largest finite value."""
    fin = v[np.isfinite(v)]
    cap = float(fin.max()) if fin.size else 1.0
    return np.where(np.isposinf(v), cap, v)


def fig_bands_vs(df: pd.DataFrame, column: str, ylabel: str, title: str):
    """One panel per other method, each overlaid with Model with Uncertainty (paper Figs. 3, 5)."""
    others = [m for m in ordered_methods(df["method"].unique()) if m != OURS]
    fig, axes = new_subplots(1, len(others), w=0.8 + 4.2 * len(others), h=3.6, sharey=True)
    mats = {m: matrix(df[df["method"] == m], column) for m in (OURS,) + tuple(others)}
    for ax, m in zip(axes[0], others):
        for name in (m, OURS):  # With Uncertainty drawn last, on top
            steps, v = mats[name]
            percentile_bands(ax, steps, _finite_cap(v), method_color(name), label=method_label(name, short=True))
        ax.set_title(f"{method_label(m)} vs\n{method_label(OURS)}", fontsize=9.5)
        ax.set_xlabel("track step k")
        _int_steps(ax)
        ax.legend(loc="best", fontsize=7)
    axes[0, 0].set_ylabel(ylabel)
    if column == "p_truth":
        axes[0, 0].set_ylim(-0.02, 1.02)
    fig.suptitle(title)
    return fig


def fig_measurements(ex: pd.DataFrame, scenario: str, classes: list[str], truth: int):
    """Each score component along the track for the example realization (paper Figs. 2, 4):
    every class's GP mean (±1 std for the truth) at the true poses, dashed at the estimates when
    they differ; the nominal and noised measurements; the N_s samples."""
    e = ex[ex["scenario"] == scenario]
    F = int(e["component"].max()) + 1
    fig, axes = new_subplots(1, F, w=0.8 + 4.0 * F, h=3.6, sharey=True)
    colors = class_colors(len(classes))
    biased = not np.allclose(e["true_x"], e["est_x"]) or not np.allclose(e["true_y"], e["est_y"])
    for f in range(F):
        ax = axes[0, f]
        g = e[e["component"] == f].sort_values("step")
        k = g["step"].to_numpy()
        cm = np.stack(g["class_mean"].to_numpy())
        cs = np.stack(g["class_std"].to_numpy())
        for c, name in enumerate(classes):
            lw = 2.0 if c == truth else 1.2
            ax.plot(k, cm[:, c], color=colors[c], lw=lw, label=f"GP mean: {name}" + (" (truth)" if c == truth else ""))
            if c == truth:
                ax.fill_between(k, cm[:, c] - cs[:, c], cm[:, c] + cs[:, c], color=colors[c], alpha=0.15, lw=0)
        if biased:
            ce = np.stack(g["class_mean_est"].to_numpy())
            for c in range(len(classes)):
                ax.plot(k, ce[:, c], color=colors[c], lw=1.0, ls="--",
                        label="GP means at the biased estimates" if c == 0 else None)
        samples = g["samples"].to_numpy()
        if max(len(s) for s in samples) > 1:
            xs = np.concatenate([np.full(len(s), kk) for kk, s in zip(k, samples)])
            ys = np.concatenate([np.asarray(s, float) for s in samples])
            ax.scatter(xs, ys, s=5, color="#888888", alpha=0.45, lw=0, label="samples (With Uncertainty)")
        ax.plot(k, g["nominal"], "kx", ms=5, label="nominal")
        if not np.allclose(g["noised"], g["nominal"]):
            ax.plot(k, g["noised"], "o", mfc="none", mec="#D55E00", ms=5, label="noised (MB, SB)")
        ax.set_title(f"score of {classes[f] if f < len(classes) else f}")
        ax.set_xlabel("track step k")
        _int_steps(ax)
    axes[0, 0].set_ylabel("classifier score")
    axes[0, -1].legend(loc="best", fontsize=6.5)
    fig.suptitle(f"Measurements along the track, one realization — {SCENARIO_TITLES.get(scenario, scenario)}")
    return fig


def fig_class_maps(models, true_xy: np.ndarray, est_xy: np.ndarray | None, classes: list[str], truth: int):
    """Per class: which class its GP mean score vector favours around the object (colour), its
    margin (opacity), the model points, the track and the biased estimates."""
    from matplotlib.colors import to_rgb

    pts_all = np.concatenate([models.X[0], true_xy] + ([est_xy] if est_xy is not None else []))
    lim = float(np.abs(pts_all).max()) * 1.08
    g = np.linspace(-lim, lim, 121)
    gx, gy = np.meshgrid(g, g)
    mean, _ = models.marginal(np.stack([gx.ravel(), gy.ravel()], -1))   # (G², C, F)
    C = len(classes)
    colors = np.array([to_rgb(c) for c in class_colors(C)])
    fig, axes = new_subplots(2, C, w=0.8 + 3.6 * C, h=4.6, height_ratios=[1.0, 0.09 * C + 0.08])
    for c in range(C):
        ax = axes[0, c]
        m = mean[:, c, :]                                  # (G², F): class c's expected scores
        top = np.argmax(m, axis=1)
        srt = np.sort(m, axis=1)
        margin = np.clip((srt[:, -1] - srt[:, -2]) / 0.4, 0.15, 1.0)
        rgb = 1 - margin[:, None] * (1 - colors[top])     # blend with white by the margin
        ax.imshow(rgb.reshape(len(g), len(g), 3), origin="lower", extent=(-lim, lim, -lim, lim),
                  interpolation="nearest")
        X = models.X[c]
        own = np.argmax(models.Y[c], axis=0)
        ax.scatter(X[:, 0], X[:, 1], c=colors[own], s=14, edgecolors="k", linewidths=0.4, zorder=3)
        ax.plot(true_xy[:, 0], true_xy[:, 1], "k.-", ms=3, lw=1, label="track (true poses)")
        ax.annotate("", xy=true_xy[-1], xytext=true_xy[-2], arrowprops={"arrowstyle": "->", "lw": 1.2})
        if est_xy is not None:
            ax.plot(est_xy[:, 0], est_xy[:, 1], ".--", color="#D55E00", ms=3, lw=0.8, label="biased estimates")
        ax.plot(0, 0, "k*", ms=9, label="object")
        # the panel is ~3.6 in wide: a long class name would squeeze the maps to nothing; the key
        # below names every class in full
        ax.set_title(f"GP model of {_short(classes[c], 26)}" + (" (truth)" if c == truth else ""))
        ax.set_aspect("equal")
        ax.set_xlabel("x (east)")
        ax.grid(False)
    axes[0, 0].set_ylabel("y (north)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    gs = axes[1, 0].get_gridspec()
    for ax in axes[1]:
        ax.remove()
    _class_map_key(fig.add_subplot(gs[1, :]), classes, colors)
    # outside the panels: inside one it can cover the map or the ticks of a small panel
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=7)
    fig.suptitle("What each class looks like around the object (colour: highest expected score; "
                 "pale: ambiguous); dots: model points")
    return fig


def _short(name: str, chars: int) -> str:
    """``name`` cut in the middle to at most ``chars`` characters."""
    if len(name) <= chars:
        return name
    head = (chars - 1) // 2
    return name[:head] + "…" + name[len(name) - (chars - 1 - head):]


def _class_map_key(ax, classes: list[str], colors: np.ndarray) -> None:
    """The class maps' colour scale: per class (row), the colour vs the score margin it encodes."""
    margin = np.linspace(0.0, 0.5, 101)
    strength = np.clip(margin / 0.4, 0.15, 1.0)
    rgb = 1 - strength[None, :, None] * (1 - colors[:, None, :])
    ax.grid(False)
    ax.imshow(rgb, aspect="auto", extent=(0.0, 0.5, len(classes) - 0.5, -0.5), interpolation="nearest")
    ax.set_yticks(range(len(classes)))
    ax.set_yticklabels([f"looks like {n}" for n in classes], fontsize=7.5)
    ax.set_xlabel("score margin of the favoured class over the next (colour scale; pale = ambiguous)")


# -- page ---------------------------------------------------------------------------------------------------
METRICS = (
    ("p_truth", "P(ground-truth class)", "P(truth)"),
    ("log10_mgr", MGR_AXIS_LABEL, "log10 MGR"),
    ("msde", "MSDE", "MSDE"),
)


def _example_poses(ex: pd.DataFrame, scenarios: list[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """True poses of the track and, where a scenario biases them, the estimates."""
    e0 = ex[ex["component"] == 0].sort_values(["scenario", "step"])
    true_xy = e0[e0["scenario"] == scenarios[0]][["true_x", "true_y"]].to_numpy(float)
    est = None
    for s in scenarios:
        es = e0[e0["scenario"] == s][["est_x", "est_y"]].to_numpy(float)
        if not np.allclose(es, true_xy):
            est = es
    return true_xy, est


def _plan(so, sim_dir: Path, scenarios: list[str]) -> list[tuple[str, Any]]:

    df, ex, classes, truth = so.results, so.example, so.classes, so.truth
    plan: list[tuple[str, Any]] = []
    if out_path(sim_dir / out_name("simulate", "models"), "models", "index").is_file():
        models = load_bank(sim_dir / out_name("simulate", "models"))
        true_xy, est = _example_poses(ex, scenarios)
        plan.append(("class_maps.png", lambda: fig_class_maps(models, true_xy, est, classes, truth)))
    summ = so.summary
    if summ.get("sweep"):
        step = (summ.get("claim_params") or {}).get("step", 15)
        plan.append(("claims_sweep.png", lambda: fig_sweep(summ["sweep"], step)))
    conf = summ.get("confident_errors") or {}
    thr = (summ.get("claim_params") or {}).get("confident_threshold")
    for s in scenarios:
        plan.append((f"{s}_measurements.png", lambda s=s: fig_measurements(ex, s, classes, truth)))
        if s in conf:
            plan.append((f"{s}_confident_errors.png", lambda s=s: fig_confident_errors(
                conf[s], thr, f"Confident errors per step — {SCENARIO_TITLES.get(s, s)}")))
        sub = df[df["scenario"] == s]
        for col, ylabel, short in METRICS:
            plan.append((f"{s}_{col}.png", lambda sub=sub, col=col, ylabel=ylabel, short=short, s=s: fig_bands_vs(
                sub, col, ylabel, f"{short} per step, percentiles 10–90 % — {SCENARIO_TITLES.get(s, s)}")))
    return plan


def _overview(page: HtmlReport, so, R: int, K: int, written: list[str]) -> None:
    cfg = so.summary.get("config", {})
    classes, truth = so.classes, so.truth
    page.section("Overview", anchor="overview")
    facts = [["classes", ", ".join(classes)], ["ground truth", classes[truth] if classes else str(truth)],
             ["realizations per scenario", R], ["track steps K", K]]
    if cfg:
        facts += [["track", f"from ({plain(cfg['track_start'][0])}, {plain(cfg['track_start'][1])}) east over "
                            f"{plain(cfg['track_length'])} units; object at the origin"],
                  ["model uncertainty", f"σ_u² ~ U(0, {plain(cfg['sigma_max'])}²), N_s = {cfg['n_samples']}"],
                  ["localization bias", f"{plain(cfg['bias_east'], signed=True)} units easting; With Uncertainty told "
                                        f"σ = {plain(cfg['sigma_loc'])}, N_x = {cfg['n_loc_samples']}"]]
    facts.append(["config hash (simulate)", so.meta.get("config_hash", MISSING)])
    page.table(["", ""], facts, cls="facts")
    page.paragraph(
        "Three classes with hand-specified, viewpoint-dependent score vectors, turned into one GP per (class, score "
        "component) on plain 2D positions around the object. A robot drives east past the object; at every step it "
        f"gets a measurement drawn from the ground-truth class's GP, conditioned on what it drew before. "
        f"'{method_label(OURS)}' gets N_s samples and, under the bias, pose samples; '{method_label(MODEL_BASED)}' "
        f"trusts the one measurement and the pose estimate; '{method_label(SIMPLE_BAYES)}' multiplies the scores "
        "(clipped to a small floor and renormalised, since a Gaussian measurement can leave the simplex). "
        + _own_model_methods() +
        f"{MGR_AXIS_LABEL}: 0 when the truth is the most likely class; its 95th percentile measures confident "
        "misclassification.")
    if "class_maps.png" in written:
        page.figure("class_maps.png", "Class models: the colour shows which class each class's GP mean score "
                    "vector favours at that position (paler = more ambiguous). Class 2 (the truth) looks like "
                    "class 1 from the south (the inverse view); class 3 has that look a little further west, so a "
                    "westward pose bias can alias class 2 into class 3.")


def _own_model_methods() -> str:
    """The methods left out because they read a model of their own (``pipeline.method.provider``)."""

    own = {p.key for p in model_providers()}
    return "".join(f"'{m.label}' does not apply here: it reads its own model of the classifier's outputs, and "
                   "these measurements are synthetic GP scores, not classifier outputs. "
                   for m in methods(attribution=False) if not m.simulation and own & set(m.needs))


def _scenario_section(page: HtmlReport, s: str, summ: dict, R: int, n_boot: int,
                      page_written: tuple[str, ...] = ()) -> None:
    page.section(SCENARIO_TITLES.get(s, s), anchor=s)
    page.figure(f"{s}_measurements.png", "Measurements along the track for one realization (paper Figs. 2/4). "
                "Lines: GP means of each class at the true poses (the truth's ±1 std shaded)"
                + ("; dashed: at the biased pose estimates that Model Based uses" if s == "localization_bias" else "")
                + ". Crosses: nominal draws; circles: noised measurements; grey dots: samples.")
    for col, _, short in METRICS:
        page.figure(f"{s}_{col}.png", f"{short} per step over {R} realizations: nested 10–90 %, 20–80 %, 30–70 %, "
                    "40–60 % bands and the median, drawn as steps, each method against With Uncertainty "
                    "(paper Figs. 3/5).")
    if f"{s}_confident_errors.png" in page_written:
        page.figure(f"{s}_confident_errors.png", f"Share of the {R} realizations whose posterior puts max P ≥ "
                    "the confident-error threshold on a wrong class, per step (the evaluate stage's definition, "
                    "pipeline.evaluation.metrics.spec.confident_errors); band: Wilson 95 % CI over realizations.")
    cell = summ.get(s) or {"methods": {}}
    page.table(["method"] + [metric_label(k, short=True) for k in TABLE],
               [[method_label(m, short=True)] + [est[k] for k in TABLE] for m, est in cell["methods"].items()],
               cls="summary", caption=f"{SCENARIO_TITLES.get(s, s)}: value [95 % CI] over {R} realizations "
                                      f"(bootstrap, {n_boot} resamples, seeded); MGR as log10.")


def build_simulate_report(sim_dir: str | Path, out_dir: str | Path, *, dpi: int = 110, run_name: str = "",
                          progress: bool = True, n_boot: int = BOOTSTRAP) -> ReportResult:
    """Render ``out_dir/index.html`` and its PNGs from the simulate stage's outputs."""

    sim_dir, out = Path(sim_dir), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    so = load_simulate(sim_dir)
    df, ex = so.results, so.example
    scenarios = list(dict.fromkeys(df["scenario"]))
    written = []
    for name, build in progress_bar(_plan(so, sim_dir, scenarios), desc="simulate figures", unit="fig",
                                    enabled=progress):
        save(build(), out / name, dpi)
        written.append(name)
    page = HtmlReport("viewfuse simulation scenarios",
                      " · ".join(x for x in (f"run {run_name}" if run_name else "", "paper §5.3",
                                             f"seed {so.meta.get('seed', '?')}") if x), badge="simulated data")
    R, K = int(df["realization"].nunique()), int(df["step"].nunique())
    claims_section(page, so.summary)
    if "claims_sweep.png" in written:
        g = so.summary["sweep"]["grid"]
        page.figure("claims_sweep.png", f"Each claim over the {g['name']} sweep's grid: GP noise variance (set on "
                    "every class model; below it the median predictive std along the track) x σ_max, "
                    f"{g['realizations']} realizations per point, the same seeds at every point. Dark: the whole "
                    "95 % CI agrees with the verdict; pale: it spans the threshold; numbers: the statistic.")
    _overview(page, so, R, K, written)
    summ = track_summary(df, metric_params(so.summary), n_boot=n_boot, seed=int(so.meta.get("seed", 0) or 0),
                         by="scenario")
    for s in scenarios:
        _scenario_section(page, s, summ, R, n_boot, tuple(written))
    page.section("Findings", anchor="findings")
    page.paragraph("The paper's qualitative findings, checked on these runs:")
    # Computed by the stage from the posteriors (reports.simulate.findings.findings), read here.
    for line in findings_text(so.summary.get("findings") or {}):
        page.paragraph(line)
    fits = so.summary.get("gp_fit") or []
    if fits:
        page.section("GP fits", anchor="gp-fits")
        page.table(["class", "component", "mean", "amplitude", "length scale", "noise", "at bound"],
                   [[d["class"], d.get("component_name") or d["component"], d["mean"], d["amplitude"],
                     d["length_scale"], d["noise"], "; ".join(d.get("at_bound") or []) or MISSING] for d in fits],
                   caption="scikit-learn marginal-likelihood fits of the hand-specified responses")
    page.write(out_path(out, "simulate", "html"))
    return ReportResult(out_path(out, "simulate", "html"), written)
