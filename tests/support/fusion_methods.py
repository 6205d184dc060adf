"""Test reference: the three fusion methods as step-by-step objects, a generic episode loop, and
``fuse_with_uncertainty_sampled`` (pose estimates -> localization samples -> fusion). Used only by
the tests, which check them against the batched ``pipeline.method.fusion`` functions.

The three fusion methods as step-by-step objects, plus a generic episode loop.

``ModelWithUncertainty``, ``ModelBased`` and ``SimpleBayes`` share one protocol:
``reset()`` forgets the track, ``update(observation)`` fuses one more view and returns the class
posterior (C,); ``log_posterior_`` holds its log. They give the same numbers as the batched
whole-track functions of ``pipeline.method.fusion`` (the tests check it) but grow the per-trajectory
Cholesky factor one row per step, so a K-step track still costs O(K³) per localization sample.
Use them for online use and readable experiment code; use ``pipeline.method.fusion`` for large batches.

``run_episodes(method, episodes)`` runs any of them over episodes and returns flat, averaged
metrics (in the spirit of habitat-lab's benchmark loop).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

import numpy as np

from pipeline.method.fusion import fuse_with_uncertainty, log_prior, logsumexp
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.gp import GPClassModels
from pipeline.evaluation.metrics import spec as _metrics
@dataclass
class Observation:
    """What one step of the track gives a method.

    inputs : GP inputs of this view: (N_x, d), one row per localization sample (Model with
        Uncertainty), or (d,) / (1, d) for the pose estimate (Model Based).
    dropout : (N_s, F) MC-dropout scores at the models' components.
    measurement : (F,) Model Based measurement; default the mean of ``dropout``.
    scores : (C,) Simple Bayes: the classifier's score of each candidate class.
    """
    inputs: np.ndarray | None = None
    dropout: np.ndarray | None = None
    measurement: np.ndarray | None = None
    scores: np.ndarray | None = None


@dataclass
class Episode:
    observations: Sequence[Observation]
    truth: int | str
    info: dict[str, Any] = field(default_factory=dict)


class _Tracks:
    """Incremental joint predictive along n trajectories for every (class, component).

    Keeps, per trajectory and (c, f), the inverse M of the Cholesky factor of the covariance of the
    past steps, the whitened past innovations y = M (z_past - μ_past), and the past inputs and
    whitened cross terms needed for the next row. ``predict`` gives the next step's conditional
    mean/variance pieces, ``commit`` appends the step once its measurement summary is known.
    """

    def __init__(self, models: GPClassModels):
        self.models = models
        self.reset()

    def reset(self) -> None:
        self.n = None
        self.k = 0
        self.X: list[np.ndarray] = []                          # per step (n, d)
        self.V: list[list[np.ndarray]] = [[] for _ in self.models.classes]  # per class, per step (F, n, N_c)
        self.M = None                                          # (n, C, F, k, k)
        self.y = None                                          # (n, C, F, k)
        self.v: list[np.ndarray] = []                          # per step (F,) past dropout variance
        self._pending = None

    def predict(self, X: np.ndarray):
        """X (n, d) -> (mu, shift, Lkk, Omega): predictive mean μ_k (n, C, F), Ω (z_past - μ_past)
        (n, C, F), sqrt(Σ_{k|past}) (n, C, F) and Ω (n, C, F, k)."""
        m = self.models
        C, F, k = m.n_classes, m.n_components, self.k
        n = len(X)
        mu = np.empty((n, C, F))
        Lkk = np.empty((n, C, F))
        shift = np.zeros((n, C, F))
        Omega = np.zeros((n, C, F, k))
        Vk_all = []
        for c in range(C):
            mu_c, Vk = m.whitened(c, X)                        # (n, F), (F, n, N_c)
            Vk_all.append(Vk)
            mu[:, c] = mu_c
            s_kk = (m.amplitude[c] + m.noise[c])[:, None] - np.einsum("fnj,fnj->fn", Vk, Vk)   # (F, n)
            if k == 0:
                l2 = 0.0
            else:
                Xp = np.stack(self.X, axis=1)                  # (n, k, d)
                Vp = np.stack(self.V[c], axis=2)               # (F, n, k, N_c)
                Kpk = np.stack([m.kernel(c, f, Xp, X[:, None, :])[..., 0] for f in range(F)])  # (F, n, k)
                s_pk = Kpk - np.einsum("fnkj,fnj->fnk", Vp, Vk)     # Σ_{past,k}
                l = np.einsum("nfij,fnj->nfi", self.M[:, c], s_pk)   # L_past⁻¹ Σ_{past,k}
                l2 = np.sum(l * l, axis=-1).T                       # (F, n)
                Omega[:, c] = np.einsum("nfi,nfij->nfj", l, self.M[:, c])  # lᵀ L_past⁻¹ = Σ_{k,past} Σ_past⁻¹
                shift[:, c] = np.einsum("nfi,nfi->nf", l, self.y[:, c])
            cond_var = s_kk - l2                               # Σ_{k|past}
            if np.any(cond_var <= 0):
                raise ValueError(f"class {m.classes[c]!r}: conditional predictive variance is not positive at "
                                 f"step {k} (white noise too small or repeated inputs)")
            Lkk[:, c] = np.sqrt(cond_var).T
        self._pending = (X, Vk_all, mu, shift, Lkk, Omega)
        return mu, shift, Lkk, Omega

    def commit(self, z: np.ndarray, v: np.ndarray | None = None) -> None:
        """Append the pending step with measurement summary z ((F,) or (n, F)) and, for Model with
        Uncertainty, the dropout variance v (F,)."""
        X, Vk_all, mu, shift, Lkk, Omega = self._pending
        n, C, F = mu.shape
        k = self.k
        d = np.broadcast_to(np.asarray(z, float), (n, F))[:, None, :] - mu
        yk = (d - shift) / Lkk
        M = np.zeros((n, C, F, k + 1, k + 1))
        y = np.empty((n, C, F, k + 1))
        if k:
            M[..., :k, :k] = self.M
            y[..., :k] = self.y
        M[..., k, :k] = -Omega / Lkk[..., None]                # row k of L⁻¹: -Ω_k / L_kk
        M[..., k, k] = 1.0 / Lkk
        y[..., k] = yk
        self.M, self.y, self.n, self.k = M, y, n, k + 1
        self.X.append(np.asarray(X, float))
        for c in range(C):
            self.V[c].append(Vk_all[c])
        self.v.append(np.zeros(F) if v is None else np.asarray(v, float))
        self._pending = None

    def past_var(self) -> np.ndarray:
        return np.stack(self.v, axis=1) if self.v else np.zeros((self.models.n_components, 0))


class _Method:
    classes: list[str]

    def _init_prior(self, prior, C):
        self._logp0 = log_prior(prior, C)
        self.log_posterior_ = self._logp0.copy()

    @property
    def posterior_(self) -> np.ndarray:
        return np.exp(self.log_posterior_)


class ModelWithUncertainty(_Method):
    """The paper's method (Algorithm 1) for one realization, N_x localization samples.

    ``update(Observation(inputs=(N_x, d), dropout=(N_s, F)))`` -> P(c | H_k) (C,).
    """

    def __init__(self, models: GPClassModels, *, prior=None, var_floor: float = 1e-6):
        self.models = models
        self.prior = prior
        self.var_floor = var_floor
        self.classes = list(models.classes)
        self.reset()

    def reset(self) -> None:
        self._tracks = _Tracks(self.models)
        self._init_prior(self.prior, self.models.n_classes)
        self._logp = None                                      # (N_x, C) per-sample log posterior

    def update(self, obs: Observation) -> np.ndarray:
        m = self.models
        X = np.atleast_2d(np.asarray(obs.inputs, float))
        S = np.atleast_2d(np.asarray(obs.dropout, float))
        if X.ndim != 2 or X.shape[1] != m.input_dim:
            raise ValueError(f"ModelWithUncertainty: inputs must be (N_x, {m.input_dim}), got {X.shape}")
        if S.ndim != 2 or S.shape[1] != m.n_components:
            raise ValueError(f"ModelWithUncertainty: dropout must be (N_s, {m.n_components}), got {S.shape}")
        if self._logp is None:
            self._logp = np.broadcast_to(self._logp0, (len(X), m.n_classes)).copy()
        elif len(X) != len(self._logp):
            raise ValueError(f"ModelWithUncertainty: {len(X)} localization samples, expected {len(self._logp)}")
        mu, shift, Lkk, Omega = self._tracks.predict(X)
        v_past = self._tracks.past_var()                       # (F, k)
        var = Lkk ** 2 + np.einsum("ncfj,fj->ncf", Omega ** 2, v_past)
        mean = mu + shift
        r = S[None, None] - mean[:, :, None, :]                # (N_x, C, N_s, F)
        ll = -0.5 * np.sum(r * r / var[:, :, None, :], axis=-1) - 0.5 * np.sum(np.log(var), axis=-1)[..., None]
        h = ll + self._logp[:, :, None]
        h -= logsumexp(h, axis=1, keepdims=True)
        self._logp = logsumexp(h, axis=-1) - math.log(len(S))
        self._tracks.commit(S.mean(axis=0), np.maximum(S.var(axis=0), self.var_floor))
        lp = logsumexp(self._logp, axis=0) - math.log(len(self._logp))
        self.log_posterior_ = lp - logsumexp(lp, axis=0)
        return self.posterior_


class ModelBased(_Method):
    """Teacy et al.: one pose-estimate trajectory, one measurement per step.

    ``update(Observation(inputs=(d,), measurement=(F,) or dropout=(N_s, F)))`` -> P(c | H_k).
    """

    def __init__(self, models: GPClassModels, *, prior=None):
        self.models = models
        self.prior = prior
        self.classes = list(models.classes)
        self.reset()

    def reset(self) -> None:
        self._tracks = _Tracks(self.models)
        self._init_prior(self.prior, self.models.n_classes)

    def update(self, obs: Observation) -> np.ndarray:
        m = self.models
        X = np.asarray(obs.inputs, float).reshape(-1, m.input_dim)
        if len(X) != 1:
            raise ValueError(f"ModelBased: one pose estimate per step, got inputs of shape {np.shape(obs.inputs)}")
        z = np.asarray(obs.measurement if obs.measurement is not None else np.mean(obs.dropout, axis=0), float)
        if z.shape != (m.n_components,):
            raise ValueError(f"ModelBased: measurement must have {m.n_components} components, got {z.shape}")
        mu, shift, Lkk, _ = self._tracks.predict(X)
        r = (z - (mu + shift)[0]) / Lkk[0]                     # (C, F) whitened innovation
        ll = np.sum(-0.5 * r * r - np.log(Lkk[0]), axis=-1)
        self._tracks.commit(z)
        lp = self.log_posterior_ + ll
        self.log_posterior_ = lp - logsumexp(lp, axis=0)
        return self.posterior_


class SimpleBayes(_Method):
    """Patten et al.: P(c|H_k) ∝ P(c|H_{k-1}) s_k[c]; ``update(Observation(scores=(C,)))``."""

    def __init__(self, classes: Sequence[str] | int, *, prior=None):
        self.classes = [f"class_{i}" for i in range(classes)] if isinstance(classes, int) else list(classes)
        self.prior = prior
        self.reset()

    def reset(self) -> None:
        self._init_prior(self.prior, len(self.classes))

    def update(self, obs: Observation) -> np.ndarray:
        s = np.asarray(obs.scores, float)
        if s.shape != (len(self.classes),) or not np.all(np.isfinite(s)) or np.any(s < 0):
            raise ValueError(f"SimpleBayes: scores must be {len(self.classes)} finite non-negative numbers, got {s}")
        lp = self.log_posterior_ + np.log(np.maximum(s, np.finfo(float).tiny))
        self.log_posterior_ = lp - logsumexp(lp, axis=0)
        return self.posterior_


def run_episodes(method, episodes: Iterable[Episode], *, progress: bool = True,
                 return_posteriors: bool = False):
    """Run ``method`` over episodes (reset, then update per observation) and average the metrics.

    Returns a flat dict: ``episodes``, ``steps``, and the means over episodes of the per-step columns
    (``metrics.STEP_COLUMNS``: p_truth, log10_mgr, msde, correct), each ``*_final`` (last step) and ``*_overall`` (all steps of an episode,
    then over episodes). With ``return_posteriors`` also a list of (K, C) log posteriors.
    """
    from tqdm.auto import tqdm

    per_ep: list[dict[str, float]] = []
    logs: list[np.ndarray] = []
    eps = list(episodes)
    for ep in tqdm(eps, desc=type(method).__name__, unit="episode", disable=not progress or len(eps) < 2):
        if isinstance(ep.truth, str):
            if ep.truth not in method.classes:
                raise ValueError(f"run_episodes: truth {ep.truth!r} is not among the classes {method.classes}")
            truth = method.classes.index(ep.truth)
        else:
            truth = int(ep.truth)
        if not ep.observations:
            raise ValueError("run_episodes: an episode has no observations")
        method.reset()
        track = []
        for obs in ep.observations:
            method.update(obs)
            track.append(method.log_posterior_.copy())
        lp = np.stack(track)                                   # (K, C)
        logs.append(lp)
        m = _metrics.step_values(lp, truth, is_log=True)
        per_ep.append({f"{name}_{which}": float(v[-1] if which == "final" else np.mean(v))
                       for name, v in m.items() for which in ("final", "overall")})
    if not per_ep:
        raise ValueError("run_episodes: no episodes")
    out: dict[str, Any] = {"episodes": len(per_ep), "steps": int(sum(len(l) for l in logs))}
    for key in per_ep[0]:
        out[key] = float(np.mean([e[key] for e in per_ep]))
    if return_posteriors:
        out["log_posteriors"] = logs
    return out


def fuse_with_uncertainty_sampled(models: GPClassModels, cam_estimates, sigma: float, dropout, *,
                                  obj_xy, yaw: float, n_samples: int, seed=0, unit_circle: bool = True,
                                  **kwargs) -> np.ndarray:
    """Model with Uncertainty from pose estimates: draw ``n_samples`` localization samples around
    each estimate (N(0, σ²I), one trajectory per sample), turn them into GP inputs relative to the
    object (``obj_xy``, ``yaw``), then ``fuse_with_uncertainty``. ``cam_estimates`` (K, 2) or
    (R, K, 2); ``seed`` an int or a ``numpy.random.Generator``."""
    samples = sample_localization(cam_estimates, sigma, n_samples, seed)
    return fuse_with_uncertainty(models, relative_inputs(samples, obj_xy, yaw, unit_circle=unit_circle),
                                 dropout, **kwargs)
