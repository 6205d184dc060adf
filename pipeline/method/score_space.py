"""The space the GP class models live in (``models.score_space``): the one place that maps the
classifier's probabilities to the numbers a GP models and a GP method measures.

The features stage writes raw softmax probabilities; the models stage fits every GP (and the
view-independent baseline's Gaussians, and the instance term) on ``to_space`` of them, and records
the space in the bank (``GPClassModels.meta["score_space"]``, saved in models/index.json); every
consumer of a GP's measurement at fusion (the cells' dropout samples, the planning worlds, the
test-domain residuals) maps the same probabilities with ``of_models``'s space. Simple Bayes and
the methods on whole probability vectors read the raw probabilities in every space.

Spaces (each applied per MC-dropout sample, so a step's mean and variance are taken in the space):

* ``probability``: the identity (the paper's space; a bounded score near 0 or 1 modelled as Gaussian).
* ``log``: log max(p, floor).
* ``logit``: log p' - log(1 - p'), p' = p clipped to [floor, 1 - floor].
* ``clr``: centred log-ratio over the whole score vector, log p'_d - mean_e log p'_e (p' = max(p,
  floor)): log scores with the vector's overall level removed.

The floor (``models.score_floor``, default 1e-6): the features store scores as float32, whose
spacing just below 1 is 6e-8, so 1 - p under ~1e-7 is rounding and logit needs a floor above it;
and a 1000-way softmax puts most outputs at 1e-8..1e-12, where the log of rounding noise would
dominate a component's variance. 1e-6 keeps every log score within [-13.8, 0] and log-odds within
±13.8, below every score a top component of the real configs takes.

The GP bounds and priors on variances (``models.amplitude_bounds``, ``noise_bounds``,
``noise_prior``) are stated for a score of range 1 (the probability space) and each space maps them
by its range squared (``variance_scale``): a log score spans log(1/floor) = 13.8, so the noise
bound 1.0 (a std of the whole range in probability) becomes 191 (a std of 13.8) and keeps its
meaning. Scaling by the range, not by the data's spread, keeps the bounds a property of the space:
the same config means the same for every class, fold and dataset, and the probability space (the
paper's, the synthetic default) is unchanged (scale 1).
"""
from __future__ import annotations

import numpy as np

SPACES = ("probability", "log", "logit", "clr")
DEFAULT = "probability"
DEFAULT_FLOOR = 1e-6
META_KEY = "score_space"
# A probability may exceed [0, 1] by float32 rounding of a softmax; beyond this it is not a probability.
_SLACK = 1e-4


def check(space: str, floor: float) -> None:
    if space not in SPACES:
        raise ValueError(f"score space must be one of {', '.join(SPACES)}, got {space!r}")
    if not (0.0 < floor < 0.5):
        raise ValueError(f"score floor must be in (0, 0.5), got {floor!r}")


def to_space(p, space: str = DEFAULT, floor: float = DEFAULT_FLOOR) -> np.ndarray:
    """Probabilities (..., D) (the last axis the whole score vector for ``clr``; any shape for the
    others) in ``space``. The identity for ``probability`` (the same array values, float64)."""
    check(space, floor)
    a = np.asarray(p, dtype=np.float64)
    if space == DEFAULT:
        return a
    if a.size and (not np.all(np.isfinite(a)) or a.min() < -_SLACK or a.max() > 1.0 + _SLACK):
        raise ValueError(f"score space {space!r}: scores must be probabilities in [0, 1], got the range "
                         f"[{np.nanmin(a):.4g}, {np.nanmax(a):.4g}] (models.score_space = 'probability' for "
                         "scores that are not)")
    if space == "logit":
        q = np.clip(a, floor, 1.0 - floor)
        return np.log(q) - np.log1p(-q)
    lg = np.log(np.maximum(a, floor))
    if space == "clr":
        return lg - lg.mean(axis=-1, keepdims=True)
    return lg


def width(space: str, floor: float = DEFAULT_FLOOR) -> float:
    """The width of the interval a score takes in ``space``: 1 (probability), log(1/floor) (log; clr,
    whose level shift moves the interval, not its width), 2 log((1 - floor)/floor) (logit)."""
    check(space, floor)
    if space == DEFAULT:
        return 1.0
    lg = float(np.log1p(-floor) - np.log(floor))   # log((1 - floor) / floor)
    return 2.0 * lg if space == "logit" else float(-np.log(floor))


def variance_scale(space: str, floor: float = DEFAULT_FLOOR) -> float:
    """The factor that maps a variance stated for a range-1 score (the bounds and priors of
    ``models``) into ``space``: its width squared; exactly 1 for probability."""
    return width(space, floor) ** 2


def variance_bounds(bounds, space: str, floor: float = DEFAULT_FLOOR) -> tuple[float, ...]:
    """(low, high) variance bounds or prior range of ``models`` in ``space``'s units; probability's
    as given (its scale is exactly 1: the paper's space and every existing run unchanged)."""
    k = variance_scale(space, floor)
    return tuple(float(b) * k for b in bounds)


def record(space: str, floor: float) -> dict:
    """What a bank records of its space (``meta["score_space"]``)."""
    check(space, floor)
    return {"space": space, "floor": float(floor)}


def of_meta(meta) -> tuple[str, float]:
    """(space, floor) from a bank's meta (a bank from before this key: the probability space)."""
    rec = (meta or {}).get(META_KEY) or {}
    space, floor = rec.get("space", DEFAULT), float(rec.get("floor", DEFAULT_FLOOR))
    check(space, floor)
    return space, floor


def of_models(models) -> tuple[str, float]:
    return of_meta(getattr(models, "meta", None))


def for_models(models, p) -> np.ndarray:
    """Probabilities (..., D) in the space ``models`` were fitted in."""
    return to_space(p, *of_models(models))
