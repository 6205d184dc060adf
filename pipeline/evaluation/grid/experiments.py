"""The localization-error experiments of the paper's section 5.5, as pure functions.

Inputs are a ``TrackData`` (true camera positions along the track, the object's position and yaw,
the MC-dropout score samples of each view, and each candidate's own score for Simple Bayes) and
fitted ``GPClassModels``. Outputs are log posterior arrays (R, K, C) per method, turned into result
rows by ``pipeline.evaluation.metrics.results`` and into the single-track tables by ``summarize``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Iterable

import numpy as np

from pipeline.evaluation.metrics import spec as M
from pipeline.method import registry
from pipeline.method.fusion import fuse_model_based
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.output_check import call_checked
from pipeline.evaluation.metrics.labels import MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY

__all__ = ["MODEL_BASED", "SIMPLE_BAYES", "WITH_UNCERTAINTY", "TrackData", "Posteriors", "track_input", "pose_free",
           "run_track", "fuse_track", "biased", "randomized", "bias_maps", "gp_rasters", "single_view_first", "summarize"]


@dataclass(frozen=True)
class TrackData:
    images: tuple[str, ...]
    cam_xy: np.ndarray       # (K, 2) camera positions, ground frame (m): the "true" poses
    obj_xy: np.ndarray       # (2,) object position (m)
    yaw: float               # object yaw (rad): object frame -> ground frame
    dropout: np.ndarray      # (K, N_s, F) MC-dropout scores of the chosen components
    own: np.ndarray | None = None  # (K, N_s, C) each candidate's own score component (Simple Bayes)
    probs: np.ndarray | None = None  # (K, N_s, D) whole probability vectors of the dropout samples

    @property
    def k(self) -> int:
        return len(self.cam_xy)

    @property
    def measurement(self) -> np.ndarray:
        """Model Based's single measurement per step: the mean of the dropout samples."""
        return self.dropout.mean(axis=1)

    def inputs(self, positions: np.ndarray) -> np.ndarray:
        """GP inputs (unit circle, object frame) for camera positions of shape (..., 2)."""
        return relative_inputs(positions, self.obj_xy, self.yaw, unit_circle=True)


def _chunks(n: int, size: int) -> Iterable[tuple[int, int]]:
    for a in range(0, n, size):
        yield a, min(n, a + size)


class Posteriors(dict):
    """{method: log posteriors}, returned with ``seconds``: {method: wall seconds of its fusion
    calls} (the evaluate stage's and the bench's time split)."""

    def __init__(self, posts=(), seconds: dict[str, float] | None = None):
        super().__init__(posts)
        self.seconds = dict(seconds or {})


def add_seconds(*parts: dict[str, float]) -> dict[str, float]:
    """Per-method seconds summed over several results' ``seconds``."""
    out: dict[str, float] = {}
    for part in parts:
        for m, sec in part.items():
            out[m] = out.get(m, 0.0) + sec
    return out


def track_input(models, track: TrackData, *, var_floor: float, estimates: np.ndarray | None = None,
                samples: np.ndarray | None = None, provided: dict | None = None,
                rng: np.random.Generator | None = None) -> registry.TrackInput:
    """What the registered methods read of one track (``pipeline.method.registry.TrackInput``);
    ``provided``: {provider key: the candidates' models} (``TrackInput.models``)."""
    return registry.TrackInput(dropout=track.dropout, gp=models, models=dict(provided or {}),
                               own=track.own, probs=track.probs,
                               estimates=estimates, samples=samples, inputs=track.inputs, var_floor=var_floor,
                               rng=rng)


def pose_free(t: registry.TrackInput, rng: Callable[[str], np.random.Generator] | None = None
              ) -> tuple[Posteriors, dict]:
    """The pose-free methods that apply to the track, fused once: ({method: log posteriors (K, C)}
    with their ``seconds``, {method: its extras} for the methods that return any, e.g. a posterior
    cloud's spread). ``rng(key)``: each method's own random stream."""
    posts, extras, seconds = {}, {}, {}
    for m in registry.methods(attribution=False):
        if not m.uses_poses and m.applies(t):
            tm = t if rng is None else replace(t, rng=rng(m.key))
            (posts[m.key], more), seconds[m.key] = _timed(call_checked, m, "fuse_with_extras", tm)
            if more:
                extras[m.key] = more
    return Posteriors(posts, seconds), extras


def run_track(models, track: TrackData, estimates: np.ndarray, sigma: float, n_x: int,
              rng: np.random.Generator, *, var_floor: float, attribution: bool = False,
              fixed: dict[str, np.ndarray] | None = None, **methods_get) -> Posteriors:
    """The methods on realizations of pose estimates (R, K, 2) -> log posteriors (R, K, C) each:
    draws the N_x localization samples around the estimates from ``rng``, then ``fuse_track``
    (``methods_get``: its ``provided`` and ``method_rng``)."""
    samples = sample_localization(estimates, sigma, n_x, rng)          # (R, N_x, K, 2)
    return fuse_track(models, track, estimates, samples, var_floor=var_floor, attribution=attribution, fixed=fixed,
                      **methods_get)


def _timed(fn, *args, **kw):
    """(``fn(*args, **kw)``, its wall seconds)."""
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0


def fuse_track(models, track: TrackData, estimates: np.ndarray, samples: np.ndarray, *, var_floor: float,
               attribution: bool = False, fixed: dict[str, np.ndarray] | None = None,
               provided: dict | None = None,
               method_rng: Callable[[str], np.random.Generator] | None = None) -> Posteriors:
    """Every registered method that applies on realizations of pose estimates (R, K, 2) and their
    localization samples (R, N_x, K, 2) -> log posteriors (R, K, C) each, in registry order.

    Log space all the way to the metrics: a confident posterior's smallest entries underflow as
    probabilities, and log MGR must stay finite.

    Model Based trusts the estimates; Model with Uncertainty fuses the N_x trajectories sampled
    around them with the stated σ (the same σ the estimate error was drawn with, as in the paper).
    A pose-free method (Simple Bayes when the track carries ``own`` scores) ignores the poses: its
    posterior, from ``fixed`` ({method: (K, C)}, fused once per track by ``pose_free``) or fused
    here, is repeated so that the methods pair up realization by realization.

    ``attribution`` adds the attribution variants (``FusionMethod.attribution``): With Uncertainty
    with one ingredient each, on the same estimates and no extra random draws, so the other
    methods' results do not change.

    The result's ``seconds``: wall seconds per method fused here (a ``fixed`` posterior's were
    counted where it was fused). ``provided``: the providers' models (``TrackInput.models``);
    ``method_rng(key)``: each method's own stream (``TrackInput.rng``).
    """
    r, seconds = len(estimates), {}
    t = track_input(models, track, var_floor=var_floor, estimates=estimates, samples=samples, provided=provided)
    out = {}
    for m in registry.methods(attribution=attribution):
        tm = t if method_rng is None else replace(t, rng=method_rng(m.key))
        if m.uses_poses:
            if m.applies(t):
                out[m.key], seconds[m.key] = _timed(call_checked, m, "fuse", tm)
            continue
        if fixed is not None:
            one = fixed.get(m.key)
        elif m.applies(t):
            one, seconds[m.key] = _timed(call_checked, m, "fuse", tm)
        else:
            one = None
        if one is not None:
            out[m.key] = np.broadcast_to(one, (r,) + one.shape).copy()
    return Posteriors(out, seconds)


def biased(models, track: TrackData, bias, sigma: float, n_x: int, rng: np.random.Generator,
           *, var_floor: float, attribution: bool = False, fixed: dict[str, np.ndarray] | None = None,
           **methods_get) -> Posteriors:
    """Every estimate shifted by the same bias (one realization): log posteriors (1, K, C)."""
    est = (track.cam_xy + np.asarray(bias, float))[None]
    return run_track(models, track, est, sigma, n_x, rng, var_floor=var_floor, attribution=attribution, fixed=fixed,
                     **methods_get)


# With Uncertainty trajectories fused per engine call by ``randomized`` (about 15 MB of sample
# positions): every call has a fixed cost (thread pool, BLAS limits, the engine's plan), which
# 25-realization calls paid hundreds of times per cell at paper grade.
BATCH_TRAJECTORIES = 100_000


def randomized(models, track: TrackData, bias, sigma: float, realizations: int, n_x: int,
               rng: np.random.Generator, *, var_floor: float, chunk: int = 25, batch: int | None = None,
               progress: Callable[[int], None] | None = None, attribution: bool = False,
               fixed: dict[str, np.ndarray] | None = None, **methods_get) -> Posteriors:
    """estimate = truth + bias + N(0, σ² I) per pose, over many realizations: log posteriors (R, K, C).

    The noise is drawn ``chunk`` realizations at a time, the estimates' errors and then their
    localization samples, which fixes the random stream; ``batch`` realizations (default: as many
    as make ``BATCH_TRAJECTORIES`` trajectories) are fused per call, which changes speed and
    memory only. ``progress`` is told the realizations of each fused batch; ``fixed`` as in
    ``fuse_track`` (as ``methods_get``: ``provided``, ``method_rng``, one stream per method across
    the batches); the result's ``seconds`` sum its batches'."""
    per_call = int(batch) if batch else max(1, BATCH_TRAJECTORIES // max(int(n_x), 1))
    out: dict[str, list[np.ndarray]] = {}
    est_parts: list[np.ndarray] = []
    smp_parts: list[np.ndarray] = []
    seconds: list[dict[str, float]] = []

    def fuse() -> None:
        est, smp = np.concatenate(est_parts), np.concatenate(smp_parts)
        est_parts.clear()
        smp_parts.clear()
        fused = fuse_track(models, track, est, smp, var_floor=var_floor, attribution=attribution, fixed=fixed,
                           **methods_get)
        for m, v in fused.items():
            out.setdefault(m, []).append(v)
        seconds.append(fused.seconds)
        if progress:
            progress(len(est))

    pending = 0
    for a, b in _chunks(realizations, chunk):
        noise = rng.normal(0.0, sigma, size=(b - a, track.k, 2)) if sigma > 0 else np.zeros((b - a, track.k, 2))
        est = track.cam_xy[None] + np.asarray(bias, float) + noise
        est_parts.append(est)
        smp_parts.append(sample_localization(est, sigma, n_x, rng))
        pending += b - a
        if pending >= per_call:
            fuse()
            pending = 0
    if pending:
        fuse()
    return Posteriors({m: np.concatenate(v, axis=0) for m, v in out.items()}, add_seconds(*seconds))


def bias_maps(models, track: TrackData, extent: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Single-view Model Based posterior of each view under a grid of 2D biases.

    Returns (axis (B,), posterior (K, C, B, B)) with posterior[..., iy, ix] for bias (axis[ix], axis[iy]).
    """
    axis = np.linspace(-extent, extent, steps)
    bx, by = np.meshgrid(axis, axis)                        # (B, B): [iy, ix]
    shifts = np.stack([bx.ravel(), by.ravel()], axis=-1)    # (B², 2)
    C = len(models.classes)
    out = np.empty((track.k, C, steps, steps))
    for k in range(track.k):
        pos = (track.cam_xy[k] + shifts)[:, None, :]        # (B², 1, 2): B² one-step tracks
        meas = np.broadcast_to(track.measurement[k], (len(shifts), 1, track.measurement.shape[1]))
        post = fuse_model_based(models, track.inputs(pos), meas, progress=False)[:, 0, :]   # (B², C)
        out[k] = post.T.reshape(C, steps, steps)
    return axis, out


def gp_rasters(models, *, grid_n: int = 61, extent: float = 1.5, ring_n: int = 180) -> dict[str, np.ndarray]:
    """GP mean/std over the unit square (Fig. 16) and on the training ring, per class and component."""
    g = np.linspace(-extent, extent, grid_n)
    gx, gy = np.meshgrid(g, g)
    pts = np.stack([gx.ravel(), gy.ravel()], -1)
    mean, var = (np.moveaxis(a, 0, -1) for a in models.marginal(pts))   # (C, F, G²)
    C, F = mean.shape[:2]
    th = np.linspace(-np.pi, np.pi, ring_n, endpoint=False)
    ring = np.stack([np.cos(th), np.sin(th)], -1)
    rmean, rvar = (np.moveaxis(a, 0, -1) for a in models.marginal(ring))
    n_max = max(len(x) for x in models.X)
    train_theta = np.full((C, n_max), np.nan)
    train_y = np.full((C, F, n_max), np.nan)
    for c in range(C):
        x = models.X[c]
        train_theta[c, : len(x)] = np.arctan2(x[:, 1], x[:, 0])
        train_y[c, :, : len(x)] = models.Y[c]
    return {
        "grid": g,
        "raster_mean": mean.reshape(C, F, grid_n, grid_n),
        "raster_std": np.sqrt(np.maximum(var, 0)).reshape(C, F, grid_n, grid_n),
        "ring_theta": th,
        "ring_mean": rmean,
        "ring_std": np.sqrt(np.maximum(rvar, 0)),
        "train_theta": train_theta,
        "train_y": train_y,
        "classes": np.array(models.classes),
        "components": np.array(models.components),
    }


def single_view_first(models, track: TrackData, truth: int, *, var_floor: float = 1e-6,
                      provided: dict | None = None) -> dict[str, float]:
    """How hard a track is: per method, the share of its views whose posterior from that view
    alone, at the true pose, ranks the truth first (1 = every view alone is enough). A method
    without a single-view reading (``single_view`` returns None, the default) has no entry."""
    t = track_input(models, track, var_floor=var_floor, estimates=track.cam_xy[None], provided=provided)
    out = {}
    for m in registry.methods(attribution=False):
        one = call_checked(m, "single_view", t) if m.applies(t) else None
        if one is not None:
            out[m.key] = float(np.mean(M.correct(one, truth, is_log=True)))
    return out | {"views": track.k}


def summarize(posts: dict[str, np.ndarray], truth: int, params: M.Params) -> dict[str, dict[str, float]]:
    """The single-track tables per method (the paper's Tables 1-2 and more): every metric of
    ``pipeline.evaluation.metrics.spec.METRICS`` over the realizations, each log10 MGR also as the
    ratio max_c P(c) / P(truth) (``metrics.with_mgr_ratios``). ``posts`` maps method -> log
    posteriors (R, K, C); ``params``: the run's metric parameters (the population's)."""
    return {method: {**M.with_mgr_ratios(M.posterior_metrics(p, truth, params=params, is_log=True)),
                     "n_realizations": int(p.shape[0])} for method, p in posts.items()}
