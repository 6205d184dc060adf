"""Simulation scenarios of the paper's §5.3: GP class models from hand-specified responses, a
straight track past the object, the measurement generator of Algorithm 2 and the realization loop.

Model confidence: ``configured_models`` keeps the fit (``model_confidence = "fitted"``) or sets
every GP's noise variance to ``hand_made_noise`` (``with_noise``), the knob the regime sweep
(``pipeline.evaluation.simulation.sweep``) turns; the paper's claims are checked in
``pipeline.evaluation.simulation.claims``.

Pure functions over arrays and the ``[simulate]`` config section; the ``simulate`` stage does the
I/O and ``reports.simulate.page`` the figures.

Frames: the object sits at the origin with yaw 0, so a robot position *is* its relative position
``r`` and the GP input (plain 2D, not projected on the unit circle). The robot moves east (+x).

Scenarios (all three methods, many realizations, deterministic for a seed):

* ``model_uncertainty`` (Algorithm 2): per step k a *nominal* measurement drawn from the
  ground-truth class's GP conditioned on the past nominal measurements; an uncertainty level
  σ_u² ~ U(0, σ_max²); a *noised* measurement ~ N(nominal, σ_u² I); N_s samples ~ N(noised,
  σ_u² I). Model Based and Simple Bayes get the noised measurement, Model with Uncertainty the
  samples. Exact poses (N_x = 1).
* ``localization_bias``: no model uncertainty (measurement = nominal, drawn at the true poses);
  every pose estimate shifted by a constant easting bias. Model Based uses the biased estimates;
  Model with Uncertainty gets the single measurement (its sample variance 0 is floored) and N_x
  localization samples N(biased estimate, σ² I) with the σ it is told.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import spec as M
from pipeline.infra.config import SimulateConfig, check_simulate
from pipeline.infra.config.checks import SIM_CLASSES
from pipeline.method import registry
from pipeline.method.output_check import call_checked
from pipeline.method.geometry import sample_localization
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.methods.simple_bayes import to_simplex  # noqa: F401 (re-exported)
from pipeline.evaluation.metrics.results import result_block
from pipeline.evaluation.metrics.labels import MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY  # noqa: F401 (re-exported)
from pipeline.infra import seeds



def methods() -> tuple[str, ...]:
    """The registered methods that apply to the simulation (``FusionMethod.simulation``): its
    measurements are synthetic GP scores, so a method that models the classifier's whole output
    vector does not."""
    return tuple(m.key for m in registry.methods(attribution=False) if m.simulation)

SCENARIOS = ("model_uncertainty", "localization_bias")
N_CLASSES = SIM_CLASSES  # the scenarios' three classes; F = 3 (one score per class, so Simple Bayes applies)


# -- class models ----------------------------------------------------------------------------------
def class_scores(sim: SimulateConfig) -> np.ndarray:
    """The hand-specified score vectors, (C, A, F): class, view angle, component."""
    return np.stack([np.asarray(getattr(sim, f"scores_class{c + 1}"), float).reshape(-1, N_CLASSES)
                     for c in range(N_CLASSES)])


def validate(sim: SimulateConfig, where: str = "config") -> None:
    """Cross-key checks of the ``[simulate]`` section (the config's own, also run at load)."""
    check_simulate(sim, where)


def model_points(sim: SimulateConfig) -> tuple[np.ndarray, np.ndarray]:
    """Training inputs X (P, 2) (every angle at every radius) and targets Y (C, F, P)."""
    ang = np.deg2rad(np.asarray(sim.view_angles_deg, float))
    rad = np.asarray(sim.view_radii, float)
    X = np.concatenate([np.stack([r * np.cos(ang), r * np.sin(ang)], -1) for r in rad])
    S = class_scores(sim)                                   # (C, A, F)
    Y = np.concatenate([S] * len(rad), axis=1).transpose(0, 2, 1)   # (C, F, P)
    return X, np.ascontiguousarray(Y)


def fit_models(sim: SimulateConfig, *, progress: bool = True) -> tuple[GPClassModels, list[dict]]:
    """One GP per (class, component), fitted with scikit-learn to the hand-specified responses."""
    X, Y = model_points(sim)
    return fit_class_models([X] * N_CLASSES, list(Y), list(sim.class_names), list(range(N_CLASSES)),
                            restarts=sim.restarts, amplitude_bounds=tuple(sim.amplitude_bounds),
                            length_scale_bounds=tuple(sim.length_scale_bounds),
                            noise_bounds=tuple(sim.noise_bounds), seed=sim.seed,
                            component_names=[f"score {n}" for n in sim.class_names], progress=progress,
                            # marginal likelihood alone: the tight [simulate] bounds do the priors' job
                            hyperprior="none")


def with_noise(models: GPClassModels, noise: float) -> GPClassModels:
    """The same class models with every GP's noise variance set to ``noise`` (prior mean, amplitude
    and length scale kept): the model-confidence knob of the regime sweep and of
    ``model_confidence = "hand_made"``. The predictive mean changes too (less smoothing)."""
    m = models
    return GPClassModels(m.classes, m.components, m.X, m.Y, m.mean, m.amplitude, m.length_scale,
                         np.full_like(m.noise, float(noise)), component_names=m.component_names, meta=m.meta)


def predictive_std(models: GPClassModels, sim: SimulateConfig) -> float:
    """Median over the track's steps, classes and components of the GP predictive std (incl. the
    noise): the scale against which σ_max is compared."""
    _, var = models.marginal(track_positions(sim.track_start, sim.track_length, sim.track_steps))
    return float(np.median(np.sqrt(np.maximum(var, 0.0))))


def configured_models(fitted: GPClassModels, sim: SimulateConfig) -> GPClassModels:
    """The models the scenarios use: the fit itself (``model_confidence = "fitted"``) or the fit
    with every noise variance set to ``hand_made_noise`` (``"hand_made"``)."""
    return fitted if sim.model_confidence == "fitted" else with_noise(fitted, sim.hand_made_noise)


def track_positions(start, length: float, steps: int) -> np.ndarray:
    """K evenly spaced positions (K, 2) on a straight eastward line from ``start``."""
    x0, y0 = (float(v) for v in start)
    xs = x0 + np.linspace(0.0, float(length), int(steps))
    return np.stack([xs, np.full_like(xs, y0)], axis=-1)


# -- the measurement generator (Algorithm 2) --------------------------------------------------------
def draw_nominal(mu: np.ndarray, cov: np.ndarray, rng: np.random.Generator, n: int | None = None,
                 *, jitter: float = 1e-10) -> np.ndarray:
    """Nominal measurements along the track: mu (F, K), cov (F, K, K) -> (K, F), or (n, K, F).

    Algorithm 2 draws step k from the GP conditioned on the nominal draws of steps 0..k-1. With
    the lower Cholesky factor ``cov = L Lᵀ`` and z ~ N(0, I), ``x = mu + L z`` is exactly that
    sequence: x_k depends on z_0..z_k only, and given x_0..x_{k-1} (equivalently z_0..z_{k-1})
    it is ``mu_k + Σ_{j<k} L_kj z_j + L_kk z_k`` = N(conditional mean, L_kk²), the GP conditional
    ``Σ_{k,past} Σ_past⁻¹`` regression and Schur complement. So one triangular product draws all
    steps in order. Components are independent (paper Eq. 17).
    """
    mu = np.asarray(mu, float)
    cov = np.asarray(cov, float)
    F, K = mu.shape
    if cov.shape != (F, K, K):
        raise ValueError(f"draw_nominal: cov must be ({F}, {K}, {K}) for mu {mu.shape}, got {cov.shape}")
    L = np.linalg.cholesky(cov + jitter * np.eye(K))
    z = rng.standard_normal((1 if n is None else n, F, K))
    x = mu[None] + np.einsum("fkj,nfj->nfk", L, z)
    x = x.transpose(0, 2, 1)                                # (n, K, F)
    return x[0] if n is None else x


def draw_sigma_u2(shape, sigma_max: float, rng: np.random.Generator) -> np.ndarray:
    """Per-step uncertainty levels σ_u² ~ U(0, σ_max²)."""
    return rng.uniform(0.0, float(sigma_max) ** 2, size=shape)


def perturb(nominal: np.ndarray, sigma_u2: np.ndarray, n_samples: int,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Noised measurements ~ N(nominal, σ_u² I) and N_s samples ~ N(noised, σ_u² I) per step.

    nominal (..., K, F), sigma_u2 (..., K) -> noised (..., K, F), samples (..., K, N_s, F).
    """
    nominal = np.asarray(nominal, float)
    sd = np.sqrt(np.asarray(sigma_u2, float))[..., None]   # (..., K, 1)
    if sd.shape[:-1] != nominal.shape[:-1]:
        raise ValueError(f"perturb: sigma_u2 {np.shape(sigma_u2)} does not match nominal {nominal.shape[:-1]}")
    noised = nominal + sd * rng.standard_normal(nominal.shape)
    eps = rng.standard_normal(nominal.shape[:-1] + (int(n_samples),) + nominal.shape[-1:])
    samples = noised[..., None, :] + sd[..., None] * eps
    return noised, samples


# -- realizations ---------------------------------------------------------------------------------------
@dataclass
class Draws:
    """What the methods get in one batch of realizations (R = batch size)."""
    nominal: np.ndarray        # (R, K, F) draws from the truth's GP at the true poses
    sigma_u2: np.ndarray       # (R, K) uncertainty levels (zeros without model uncertainty)
    noised: np.ndarray         # (R, K, F) Model Based / Simple Bayes measurement
    samples: np.ndarray        # (R, K, N_s, F) Model with Uncertainty's measurement samples
    estimates: np.ndarray      # (R, K, 2) pose estimates (Model Based)
    loc_samples: np.ndarray    # (R, N_x, K, 2) localization samples (Model with Uncertainty)


def realization_rng(seed: int, scenario: str, r: int) -> np.random.Generator:
    """One generator per (scenario, realization): results do not depend on the batch size."""
    return seeds.stream(seed, SCENARIOS.index(scenario), r)   # the scenario by its place: numbers kept


def draw_realization(scenario: str, sim: SimulateConfig, mu: np.ndarray, cov: np.ndarray,
                     true_xy: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One realization's inputs for the three methods. ``mu`` (F, K), ``cov`` (F, K, K): the
    ground-truth class's joint predictive at the true poses ``true_xy`` (K, 2)."""
    K = len(true_xy)
    nominal = draw_nominal(mu, cov, rng)                    # (K, F)
    if scenario == "model_uncertainty":
        s2 = draw_sigma_u2(K, sim.sigma_max, rng)
        noised, samples = perturb(nominal, s2, sim.n_samples, rng)
        est = true_xy.copy()
        loc = true_xy[None].copy()                          # N_x = 1: exact poses
    elif scenario == "localization_bias":
        s2 = np.zeros(K)
        noised = nominal.copy()
        samples = nominal[:, None, :].copy()                # one sample: variance 0, floored by the fusion
        est = true_xy + np.array([sim.bias_east, 0.0])
        loc = sample_localization(est, sim.sigma_loc, sim.n_loc_samples, rng)
    else:
        raise ValueError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
    return {"nominal": nominal, "sigma_u2": s2, "noised": noised, "samples": samples,
            "estimates": est, "loc_samples": loc}


def draw_batch(scenario: str, sim: SimulateConfig, mu, cov, true_xy, realizations) -> Draws:
    parts = [draw_realization(scenario, sim, mu, cov, true_xy, realization_rng(sim.seed, scenario, r))
             for r in realizations]
    return Draws(**{k: np.stack([p[k] for p in parts]) for k in parts[0]})


def fuse_batch(models: GPClassModels, d: Draws, sim: SimulateConfig) -> dict[str, np.ndarray]:
    """The simulation's methods on one batch: posteriors (R, K, C) per method (prior uniform),
    each checked (``pipeline.method.output_check``: shape, values, normalisation; named by key)."""
    shape = d.noised.shape[:2] + (len(models.classes),)
    out = {}
    for key in methods():
        m = registry.get(key)
        out[key] = call_checked(m, "simulate", d, shape=shape, call=lambda draws: m.simulate(models, draws, sim))
    return out


@dataclass
class ScenarioResult:
    scenario: str
    posteriors: dict[str, np.ndarray]          # method -> (R, K, C)
    example: dict[str, np.ndarray]             # the example realization's draws (see Draws)
    true_xy: np.ndarray                        # (K, 2)
    truth: int                                 # 0-based ground-truth class
    extra: dict[str, Any] = field(default_factory=dict)


def run_scenario(models: GPClassModels, scenario: str, sim: SimulateConfig, *,
                 realizations: int | None = None,
                 progress: Callable[[int], None] | None = None) -> ScenarioResult:
    """All realizations of one scenario, fused in batches of ``sim.chunk``."""
    R = sim.realizations if realizations is None else int(realizations)
    truth = sim.truth_class - 1
    true_xy = track_positions(sim.track_start, sim.track_length, sim.track_steps)
    mu, cov = models.predict(true_xy)                       # (C, F, K), (C, F, K, K)
    mu_t, cov_t = mu[truth], cov[truth]
    keys = methods()
    out: dict[str, list[np.ndarray]] = {m: [] for m in keys}
    example: dict[str, np.ndarray] = {}
    ex = min(sim.example_realization, R - 1)
    for a in range(0, R, sim.chunk):
        idx = range(a, min(R, a + sim.chunk))
        d = draw_batch(scenario, sim, mu_t, cov_t, true_xy, idx)
        post = fuse_batch(models, d, sim)
        for m in keys:
            out[m].append(post[m])
        if a <= ex < idx.stop:
            example = {k: getattr(d, k)[ex - a] for k in Draws.__dataclass_fields__}
        if progress:
            progress(len(idx))
    posts = {m: np.concatenate(v) for m, v in out.items()}
    for m, p in posts.items():
        if not np.all(np.isfinite(p)):
            raise RuntimeError(f"simulate/{scenario}: {m} produced non-finite posteriors")
    return ScenarioResult(scenario, posts, example, true_xy, truth)


# -- tables -------------------------------------------------------------------------------------------
def result_columns(res: ScenarioResult) -> dict[str, np.ndarray]:
    """One row per (method, realization, step): posterior and its per-step metric columns, the
    evaluate stage's layout (``pipeline.evaluation.metrics.results.result_block``) plus ``scenario``."""
    return result_block(dict(res.posteriors), res.truth, is_log=False, scenario=res.scenario)


def example_columns(res: ScenarioResult, models: GPClassModels) -> dict[str, np.ndarray]:
    """The example realization per (step, component), with every class's GP mean and std at the
    true and at the estimated poses (the measurement figures, paper Figs. 2 and 4); per-row
    vectors (samples, class means and stds) as 2D arrays."""
    e = res.example
    K, F = e["nominal"].shape
    mu_t, var_t = models.marginal(res.true_xy)              # (K, C, F)
    mu_e, _ = models.marginal(e["estimates"])
    k, f = np.repeat(np.arange(K), F), np.tile(np.arange(F), K)
    return {
        "scenario": np.full(K * F, res.scenario, dtype=object),
        "step": k.astype(np.int64), "component": f.astype(np.int64),
        "true_x": res.true_xy[k, 0].astype(float), "true_y": res.true_xy[k, 1].astype(float),
        "est_x": e["estimates"][k, 0].astype(float), "est_y": e["estimates"][k, 1].astype(float),
        "nominal": e["nominal"][k, f].astype(float), "noised": e["noised"][k, f].astype(float),
        "sigma_u2": np.asarray(e["sigma_u2"], float)[k],
        "samples": _rows_of(e["samples"][k, :, f].astype(float)),   # N_s differs between scenarios
        "class_mean": mu_t[k, :, f].astype(float),
        "class_std": np.sqrt(np.maximum(var_t[k, :, f], 0.0)),
        "class_mean_est": mu_e[k, :, f].astype(float),
    }


def _rows_of(a: np.ndarray) -> np.ndarray:
    out = np.empty(len(a), dtype=object)
    out[:] = list(a)
    return out


def summarize(df: pd.DataFrame, params: M.Params) -> pd.DataFrame:
    """Per (scenario, method): every metric of ``pipeline.evaluation.metrics.spec.METRICS`` over the
    realizations, each log10 MGR also as the ratio (``metrics.with_mgr_ratios``)."""
    rows = []
    for (scenario, method), g in df.groupby(["scenario", "method"], sort=False):
        rows.append({"scenario": scenario, "method": method,
                     **M.with_mgr_ratios(M.scalars(M.matrices(g), params=params)),
                     "realizations": int(g["realization"].nunique())})
    return pd.DataFrame(rows)
