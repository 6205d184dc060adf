"""Frames on the ground plane (docs/design.md §4): rotations, relative GP inputs, pose sampling.

Conventions: 2D, right-handed seen from above, metres, angles in radians counter-clockwise.
The object frame has origin ``o`` and yaw ``ψ``; a camera at ``p`` sees the object from the
relative position ``r = Rot(-ψ)(p - o)``, and the GP input is ``r / ‖r‖`` (paper Eq. 47) or, for
the simulation scenarios, ``r`` itself.
"""
from __future__ import annotations

import numpy as np


def rot(theta) -> np.ndarray:
    """Rotation matrices Rot(θ), shape (..., 2, 2), for θ of any shape."""
    t = np.asarray(theta, dtype=float)
    c, s = np.cos(t), np.sin(t)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def project_unit_circle(r: np.ndarray, *, what: str = "relative position") -> np.ndarray:
    """Project 2D vectors (..., 2) onto the unit circle (paper Eq. 47): the GP input of every view,
    BigBIRD training views (``stages.features``) and AVD tracks alike. A vector within 1e-12 of
    zero has no direction (error). ``numpy.hypot`` gives the length: no overflow, and rounding that
    does not depend on how the caller batches its vectors."""
    r = np.asarray(r, dtype=float)
    if r.shape[-1:] != (2,):
        raise ValueError(f"{what}: vectors must end in 2 coordinates, got shape {r.shape}")
    n = np.hypot(r[..., 0], r[..., 1])[..., None]
    if not np.all(np.isfinite(r)):
        raise ValueError(f"{what}: non-finite coordinates")
    if np.any(n <= 1e-12):
        bad = int(np.count_nonzero(n <= 1e-12))
        raise ValueError(f"{what}: {bad} camera position(s) coincide with the object: no viewing direction")
    return r / n


def relative_inputs(cam_xy, obj_xy, yaw, *, unit_circle: bool = True) -> np.ndarray:
    """GP inputs ``Rot(-ψ)(p_cam - o)`` (optionally projected on the unit circle), shape (..., 2).

    ``cam_xy`` (..., 2) camera positions in the ground frame; ``obj_xy`` (2,) or broadcastable;
    ``yaw`` the object yaw ψ (scalar or broadcastable to the leading shape).
    """
    p = np.asarray(cam_xy, dtype=float)
    o = np.asarray(obj_xy, dtype=float)
    if p.shape[-1] != 2 or o.shape[-1] != 2:
        raise ValueError(f"relative_inputs: positions must end in 2 coordinates, got {p.shape} and {o.shape}")
    R = rot(-np.asarray(yaw, dtype=float))
    r = np.einsum("...ij,...j->...i", R, p - o)
    if unit_circle:
        return project_unit_circle(r)
    return r


def bearing(r: np.ndarray) -> np.ndarray:
    """Angle (rad, in (-π, π]) of 2D vectors (..., 2)."""
    r = np.asarray(r, dtype=float)
    return np.arctan2(r[..., 1], r[..., 0])


def sample_localization(estimates, sigma: float, n: int, rng) -> np.ndarray:
    """Localization samples: each pose estimate plus independent N(0, σ²I) noise.

    ``estimates`` (K, 2) or (R, K, 2) -> (n, K, 2) or (R, n, K, 2). Each sample is one whole
    trajectory, drawn once and reused along the track (docs/design.md §5). ``rng`` is a
    ``numpy.random.Generator`` or an integer seed. ``sigma = 0`` gives n copies of the estimates.
    """
    est = np.asarray(estimates, dtype=float)
    if est.ndim not in (2, 3) or est.shape[-1] != 2:
        raise ValueError(f"sample_localization: estimates must be (K, 2) or (R, K, 2), got {est.shape}")
    if not np.all(np.isfinite(est)):
        raise ValueError("sample_localization: estimates contain NaN or infinite coordinates")
    if sigma < 0 or not np.isfinite(sigma):
        raise ValueError(f"sample_localization: sigma must be finite and >= 0, got {sigma}")
    if n < 1:
        raise ValueError(f"sample_localization: n must be >= 1, got {n}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    if est.ndim == 2:
        noise = gen.standard_normal((n,) + est.shape)
        return est[None] + sigma * noise
    noise = gen.standard_normal((est.shape[0], n) + est.shape[1:])
    return est[:, None] + sigma * noise
