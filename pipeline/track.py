"""The evaluation track: which AVD views of the target, in which order, and where the object is.

Pure functions over arrays (the evaluate stage does the I/O):
- ``bearing_rays`` turns box centres into 2D rays in the ground frame;
- ``intersect_rays`` estimates the object's 2D position by least squares;
- ``select_track`` picks K views at distinct grid points, roughly facing the object, spread over an
  arc around it and ordered by bearing, i.e. a path a robot could drive.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class TrackError(ValueError):
    """The scan cannot give a usable track (too few views, degenerate geometry)."""


def bearing_rays(cam_xy: np.ndarray, heading: np.ndarray, box_cx: np.ndarray, fx: float, cx: float):
    """Ray origins and unit directions through the box centres (ground frame).

    The image x axis points right, which seen from above is clockwise from the optical axis, so a box
    centre at column u lies at angle ``heading - atan((u - cx) / fx)``.
    """
    ang = np.asarray(heading, float) - np.arctan2(np.asarray(box_cx, float) - cx, fx)
    d = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    return np.asarray(cam_xy, float), d


def intersect_rays(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Least-squares point closest to all rays: sum_i (I - d_i d_iᵀ)(o - p_i) = 0."""
    origins = np.asarray(origins, float)
    dirs = np.asarray(dirs, float)
    if len(origins) < 2:
        raise TrackError(f"need at least 2 views of the object to locate it, got {len(origins)}")
    P = np.eye(2)[None] - dirs[:, :, None] * dirs[:, None, :]
    A = P.sum(0)
    b = np.einsum("nij,nj->i", P, origins)
    if np.linalg.cond(A) > 1e8:
        raise TrackError("the views' rays are (nearly) parallel: cannot locate the object")
    return np.linalg.solve(A, b)


@dataclass(frozen=True)
class TrackChoice:
    index: np.ndarray        # indices into the candidate arrays, in path order
    bearing_deg: np.ndarray  # bearing of each chosen camera seen from the object
    arc_deg: float           # bearing span of the track


def select_track(cam_xy: np.ndarray, obj_xy: np.ndarray, facing_err: np.ndarray, k: int,
                 *, grid_step: float = 0.3, max_arc_deg: float = 180.0) -> TrackChoice:
    """Choose ``k`` views spread in bearing around the object, one per grid point.

    ``facing_err`` is how far (radians) the object is from each view's optical axis: at a grid point
    the view facing the object best is kept. Among the remaining points, the k whose bearings best
    cover the widest arc (up to ``max_arc_deg``) are taken, ordered by bearing.
    """
    cam_xy = np.asarray(cam_xy, float)
    facing_err = np.abs(np.asarray(facing_err, float))
    # One view per grid point: the one facing the object best.
    cell = np.round(cam_xy / (grid_step / 2)).astype(np.int64)
    best: dict[tuple, int] = {}
    for i, key in enumerate(map(tuple, cell)):
        if key not in best or facing_err[i] < facing_err[best[key]]:
            best[key] = i
    cand = np.array(sorted(best.values()), dtype=np.int64)
    if len(cand) < k:
        raise TrackError(f"only {len(cand)} distinct viewpoints see the target; the track needs {k} "
                         "(lower evaluate.track_length or raise evaluate.max_difficulty)")
    rel = cam_xy[cand] - np.asarray(obj_xy, float)
    bear = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
    order = np.argsort(bear, kind="stable")
    cand, bear, dist = cand[order], bear[order], np.hypot(*rel[order].T)
    n = len(cand)
    best_choice = None
    for s in range(n):
        # Bearings unwrapped from this start, within the allowed arc.
        b = (bear - bear[s]) % 360.0
        inside = np.nonzero(b <= max_arc_deg + 1e-9)[0]
        if len(inside) < k:
            continue
        bi = b[inside]
        span = bi.max()
        targets = np.linspace(0.0, span, k)
        picked: list[int] = []
        for t in targets:
            # nearest unused candidate in bearing; ties go to the closer camera
            cost = np.abs(bi - t) + 1e-3 * dist[inside]
            cost[picked] = np.inf
            picked.append(int(np.argmin(cost)))
        picked_sorted = sorted(picked, key=lambda j: bi[j])
        sel = inside[picked_sorted]
        gaps = np.diff(np.sort(bi[picked_sorted]))
        score = (span, gaps.min() if len(gaps) else 0.0, -dist[sel].mean())
        if best_choice is None or score > best_choice[0]:
            best_choice = (score, sel, span)
    if best_choice is None:  # pragma: no cover - len(cand) >= k guarantees a window at 360
        raise TrackError("could not select a track")
    _, sel, span = best_choice
    return TrackChoice(index=cand[sel], bearing_deg=bear[sel], arc_deg=float(span))


def facing_error(cam_xy: np.ndarray, heading: np.ndarray, obj_xy: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) between each optical axis and the direction to the object."""
    rel = np.asarray(obj_xy, float) - np.asarray(cam_xy, float)
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - np.asarray(heading, float)
    return np.abs((ang + np.pi) % (2 * np.pi) - np.pi)
