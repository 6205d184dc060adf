"""The regime sweep: the paper's §5.3 claims over a grid of model confidence and σ_max.

Model confidence is the GP noise variance v, set on every GP of the fitted class models
(``simulation.with_noise``: prior mean, amplitude and length scale as fitted). Its effect is read
as the ratio of σ_max to the models' predictive std along the track (``simulation.predictive_std``):
a hand-made model that is sure of its scores has a small std, so even a moderate σ_max is many of
its standard deviations. The model-uncertainty scenario runs at every (v, σ_max); the
localization-bias scenario has no σ_max and runs once per v (its claims are copied along σ_max).

Every grid point uses the same realization seeds (``simulation.realization_rng``), the first
``realizations`` of them: common random numbers, so neighbouring points differ by the setting, not
by the draws, and a point equal to the default setting reproduces the default run's first
realizations exactly. Deterministic for a seed.

``claims_block`` is what the ``simulate`` stage writes about the claims: the table on its own run,
the confident errors per step, the sweep and its computed summary, the best point rerun at full size.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from pipeline.evaluation.simulation import claims as CL
from pipeline.evaluation.simulation import scenarios as S
from pipeline.infra.config import SimulateConfig
from pipeline.method.gp import GPClassModels
from pipeline.infra.progress import bar as progress_bar

MU, LB = CL.MU, CL.LB


@dataclass(frozen=True)
class Grid:
    name: str
    noise: tuple[float, ...]
    sigma_max: tuple[float, ...]
    realizations: int


def default_point(models: GPClassModels, sim: SimulateConfig) -> tuple[float, float]:
    """(noise variance, σ_max) of the configured default: the median noise of its models."""
    return float(np.median(models.noise)), float(sim.sigma_max)


def grid(sim: SimulateConfig, which: str | None = None, default: tuple[float, float] | None = None) -> Grid:
    """The configured grid (``simulate.sweep`` = small / full); the default point is added to the
    axes so it is a computed cell, not an interpolation."""
    which = sim.sweep if which is None else which
    if which == "off":
        raise ValueError("grid: simulate.sweep is 'off'")
    full = which == "full"
    noise = list(sim.sweep_full_noise if full else sim.sweep_noise)
    sig = list(sim.sweep_sigma_max if not full else sim.sweep_full_sigma_max)
    if default is not None:
        noise.append(default[0])
        sig.append(default[1])
    # Merge values equal to a few significant digits (a fitted noise at a bound is 0.005000000000000002).
    def axis(v):
        return tuple(sorted({float(f"{x:.6g}") for x in v}))
    return Grid(which, axis(noise), axis(sig), int(sim.sweep_full_realizations if full else sim.sweep_realizations))


def run_sweep(fitted: GPClassModels, sim: SimulateConfig, g: Grid, p: CL.ClaimParams,
              progress: Callable[[int], None] | None = None) -> list[dict[str, Any]]:
    """One record per (noise, σ_max, claim): the claim's record (``claims.evaluate_claim``) plus
    noise, sigma_max, predictive_std and ratio = σ_max / predictive_std."""
    truth = sim.truth_class - 1
    out: list[dict[str, Any]] = []
    for v in g.noise:
        models = S.with_noise(fitted, v)
        sd = S.predictive_std(models, sim)
        lb: list[dict] = []
        if LB in sim.scenarios:
            res = S.run_scenario(models, LB, sim, realizations=g.realizations)
            lb = CL.evaluate_claims({LB: res.posteriors}, truth, p)
            if progress:
                progress(1)
        for s in g.sigma_max:
            recs = list(lb)
            if MU in sim.scenarios:
                res = S.run_scenario(models, MU, dataclasses.replace(sim, sigma_max=s), realizations=g.realizations)
                recs = CL.evaluate_claims({MU: res.posteriors}, truth, p) + recs
                if progress:
                    progress(1)
            for r in recs:
                out.append({"noise": v, "sigma_max": s, "predictive_std": sd,
                            "ratio": s / sd if sd > 0 else float("inf"), **r})
    return out


def steps(sim: SimulateConfig, g: Grid) -> int:
    """Scenario runs the sweep makes (for a progress bar)."""
    return len(g.noise) * ((MU in sim.scenarios) * len(g.sigma_max) + (LB in sim.scenarios))


# -- reading the sweep -----------------------------------------------------------------------------------
def points(records: list[dict]) -> dict[tuple[float, float], dict[str, dict]]:
    """{(noise, σ_max): {claim key: record}}."""
    out: dict[tuple[float, float], dict[str, dict]] = {}
    for r in records:
        out.setdefault((r["noise"], r["sigma_max"]), {})[r["key"]] = r
    return out


def best_point(records: list[dict]) -> tuple[float, float] | None:
    """The grid point where the most claims hold; ties: more of them with the whole CI on the
    holding side, then the smallest σ_max, then the largest noise (the least departure from a
    fitted model)."""
    pts = points(records)
    if not pts:
        return None

    def score(item):
        (v, s), recs = item
        return (sum(r["holds"] for r in recs.values()), sum(r["ci_side"] == "holds" for r in recs.values()), -s, v)
    return max(pts.items(), key=score)[0]


def _span(vals: list[float], fmt: str = "{:.3g}") -> str:
    if not vals:
        return "—"
    lo, hi = min(vals), max(vals)
    return fmt.format(lo) if lo == hi else f"{fmt.format(lo)} to {fmt.format(hi)}"


def regime_summary(records: list[dict], default: tuple[float, float]) -> dict[str, Any]:
    """Computed description of the sweep: per claim where it holds; whether the model-uncertainty
    claims (or all claims) hold together anywhere; the best point; the default point."""
    pts = points(records)
    keys = [c.key for c in CL.CLAIMS if any(c.key in r for r in pts.values())]
    per_claim = {}
    for k in keys:
        hold = [(v, s, r[k]["ratio"]) for (v, s), r in pts.items() if r[k]["holds"]]
        per_claim[k] = {"holds_at": len(hold), "points": len(pts),
                        "ratio_range": [min(h[2] for h in hold), max(h[2] for h in hold)] if hold else None,
                        "noise_range": [min(h[0] for h in hold), max(h[0] for h in hold)] if hold else None,
                        "sigma_max_range": [min(h[1] for h in hold), max(h[1] for h in hold)] if hold else None,
                        "rule": best_rule(records, k)}
    mu_keys = [k for k in keys if CL.BY_KEY[k].scenario == MU]
    mu_all = [(v, s) for (v, s), r in pts.items() if mu_keys and all(r[k]["holds"] for k in mu_keys)]
    all_ = [(v, s) for (v, s), r in pts.items() if all(r[k]["holds"] for k in keys)]
    best = best_point(records)
    dflt = pts.get(_nearest(pts, default))
    return {
        "claims": per_claim, "points": len(pts),
        "mu_all_hold_at": [list(p) for p in sorted(mu_all)],
        "all_hold_at": [list(p) for p in sorted(all_)],
        "never_hold": [k for k in keys if per_claim[k]["holds_at"] == 0],
        "best": None if best is None else {"noise": best[0], "sigma_max": best[1],
                                           "holds": [k for k in keys if pts[best][k]["holds"]],
                                           "ratio": next(iter(pts[best].values()))["ratio"]},
        "default": {"noise": default[0], "sigma_max": default[1],
                    "holds": [k for k in keys if dflt and dflt[k]["holds"]]},
        "sentence": sentence(records, default),
    }


AXES = (("sigma_max", "σ_max", "{:g}"), ("ratio", "σ_max / predictive std", "{:.1f}"),
        ("noise", "GP noise variance", "{:.3g}"))


def best_rule(records: list[dict], key: str) -> dict[str, Any]:
    """The one-threshold rule (σ_max, the ratio or the noise variance, >= or <= a grid value) that
    agrees with the claim's verdict at the most grid points: a computed "where it holds"."""
    rows = [r for r in records if r["key"] == key]
    y = np.array([r["holds"] for r in rows], bool)
    best = None
    for field_, label, fmt in AXES:
        x = np.array([r[field_] for r in rows], float)
        for t in np.unique(x):
            for op, pred in ((">=", x >= t), ("<=", x <= t)):
                agree = int(np.sum(pred == y))
                cand = (agree, -AXES.index((field_, label, fmt)))
                if best is None or cand > best[0]:
                    best = (cand, {"field": field_, "op": op, "threshold": float(t), "agree": agree,
                                   "text": f"{label} {'≥' if op == '>=' else '≤'} {fmt.format(t)}"})
    return best[1] if best else {"field": None, "op": None, "threshold": float("nan"), "agree": 0, "text": "—"}


def _nearest(pts, default):
    if not pts:
        return None
    return min(pts, key=lambda p: (abs(np.log(p[0] / default[0])), abs(p[1] - default[1])))


def sentence(records: list[dict], default: tuple[float, float]) -> str:
    """Where the paper's claims hold and where they do not, in words, from the sweep's records."""
    pts = points(records)
    if not pts:
        return "The sweep did not run."
    keys = [c.key for c in CL.CLAIMS if any(c.key in r for r in pts.values())]
    mu_keys = [k for k in keys if CL.BY_KEY[k].scenario == MU]
    n = len(pts)
    parts = []
    mu_all = [p for p, r in pts.items() if mu_keys and all(r[k]["holds"] for k in mu_keys)]
    if mu_keys:
        if mu_all:
            rr = [pts[p][mu_keys[0]]["ratio"] for p in mu_all]
            parts.append(f"All {len(mu_keys)} model-uncertainty claims hold together at {len(mu_all)} of {n} grid "
                         f"points (GP noise variance {_span([p[0] for p in mu_all])}, σ_max "
                         f"{_span([p[1] for p in mu_all])}, σ_max / predictive std {_span(rr, '{:.1f}')}).")
        else:
            parts.append(f"The {len(mu_keys)} model-uncertainty claims hold together at none of the {n} grid points.")
    never = [k for k in keys if not any(r[k]["holds"] for r in pts.values())]
    for k in never:
        vals = [r[k]["value"] for r in pts.values()]
        parts.append(f"“{CL.BY_KEY[k].statement}” holds nowhere on the grid (statistic "
                     f"{_span(vals)}, needs {CL.BY_KEY[k].op} {CL.BY_KEY[k].threshold:g}).")
    always = [k for k in keys if all(r[k]["holds"] for r in pts.values())]
    if always:
        parts.append("Holding at every grid point: " + "; ".join(f"“{CL.BY_KEY[k].statement}”" for k in always) + ".")
    for k in keys:
        if k in never or k in always:
            continue
        hold = sum(r[k]["holds"] for r in pts.values())
        rule = best_rule(records, k)
        parts.append(f"“{CL.BY_KEY[k].statement}” holds at {hold} of {n} points, mostly where {rule['text']} "
                     f"(that rule agrees with the verdict at {rule['agree']} of {n}).")
    best = best_point(records)
    if best is not None:
        b = pts[best]
        parts.append(f"Most claims hold at GP noise variance {best[0]:.3g}, σ_max {best[1]:g} "
                     f"(σ_max / predictive std {next(iter(b.values()))['ratio']:.1f}): "
                     f"{sum(r['holds'] for r in b.values())} of {len(b)}.")
    d = pts.get(_nearest(pts, default))
    if d:
        parts.append(f"At the default (GP noise variance {default[0]:.3g}, σ_max {default[1]:g}): "
                     f"{sum(r['holds'] for r in d.values())} of {len(d)} hold.")
    return " ".join(parts)


# -- the stage's block --------------------------------------------------------------------------------------
def claims_block(fitted: GPClassModels, models: GPClassModels, sim: SimulateConfig,
                 posts: dict[str, dict[str, np.ndarray]]) -> tuple[dict[str, Any], dict[str, float]]:
    """What ``simulate/summary.json`` holds about the paper's claims, and its timings: the claims
    on the stage's own posteriors ``posts`` ({scenario: {method: (R, K, C)}}, from ``models``),
    the confident-error rate per step, the sweep (unless ``simulate.sweep = "off"``) and, where
    the sweep's best point is not the default, the claims rerun there at ``sim.realizations``."""

    truth = sim.truth_class - 1
    p = CL.ClaimParams(step=sim.claim_step, confident_threshold=sim.confident_threshold, seed=sim.seed)
    block: dict[str, Any] = {
        "claims": CL.evaluate_claims(posts, truth, p),
        "claim_params": {"step": sim.claim_step, "confident_threshold": sim.confident_threshold,
                         "model_confidence": sim.model_confidence, "predictive_std": S.predictive_std(models, sim)},
        "confident_errors": {sc: CL.confident_errors_by_step(ps, truth, sim.confident_threshold)
                             for sc, ps in posts.items()},
        "sweep": None, "best_regime": None,
    }
    timings: dict[str, float] = {}
    if sim.sweep == "off":
        return block, timings
    t0 = time.perf_counter()
    default = default_point(models, sim)
    g = grid(sim, default=default)
    with progress_bar(total=steps(sim, g), desc=f"sweep ({g.name})", unit="run") as bar:
        records = run_sweep(fitted, sim, g, p, progress=bar.update)
    regime = regime_summary(records, default)
    block["sweep"] = {"grid": {"name": g.name, "noise": list(g.noise), "sigma_max": list(g.sigma_max),
                               "realizations": g.realizations},
                      "default": {"noise": default[0], "sigma_max": default[1]},
                      "records": records, "summary": regime}
    timings["sweep"] = time.perf_counter() - t0
    best = regime["best"]
    if best and (abs(np.log(best["noise"] / default[0])) > 1e-9 or best["sigma_max"] != default[1]):
        t0 = time.perf_counter()
        bsim = dataclasses.replace(sim, sigma_max=best["sigma_max"])
        bmod = S.with_noise(fitted, best["noise"])
        bposts = {sc: S.run_scenario(bmod, sc, bsim).posteriors for sc in sim.scenarios}
        block["best_regime"] = {"noise": best["noise"], "sigma_max": best["sigma_max"],
                                "predictive_std": S.predictive_std(bmod, sim), "realizations": sim.realizations,
                                "claims": CL.evaluate_claims(bposts, truth, p)}
        timings["best_regime"] = time.perf_counter() - t0
    return block, timings
