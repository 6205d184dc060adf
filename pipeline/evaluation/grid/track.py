"""The evaluation track: which AVD views of the target, in which order, and where the object is.

Pure functions over arrays (the evaluate stage does the I/O):
- ``bearing_rays`` turns box centres into 2D rays in the ground frame;
- ``intersect_rays`` estimates the object's 2D position by least squares;
- ``select_tracks`` picks several paths per target for the population evaluation, each K views
  at distinct grid points, roughly facing the object, spread over an arc around it and ordered by
  bearing (a path a robot could drive): different start bearings, both directions of travel, near
  and far where the scan offers both;
- ``grid_step`` reads the capture grid's spacing off the camera positions (or grid points).
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


def grid_step(cam_xy: np.ndarray, grid_id: np.ndarray | None = None) -> float:
    """The capture grid's spacing (m): the median distance from each grid point to its nearest
    neighbour. Without ``grid_id`` a grid point is a distinct camera position (to the mm), as in
    the synthetic scans, where the headings of a stop share one centre; with ``grid_id`` (one id
    per camera, ``pipeline.evaluation.grid.viewpoints``) it is the mean centre of the cameras sharing an
    id, as real reconstructions need (a stop's centres lie ~2 cm apart)."""
    xy = np.asarray(cam_xy, float)
    if grid_id is not None:
        gid = np.asarray(grid_id)
        if gid.shape != (len(xy),):
            raise ValueError(f"grid_id has shape {gid.shape}, expected ({len(xy)},): one id per camera")
        keys, inv = np.unique(gid, return_inverse=True)
        xy = np.stack([np.bincount(inv, xy[:, a], len(keys)) / np.bincount(inv, None, len(keys)) for a in (0, 1)], axis=1)
    pts = np.unique(np.round(xy, 3), axis=0)
    if len(pts) < 2:
        raise TrackError(f"cannot read a grid step off {len(pts)} distinct camera position(s)")
    d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def _viewpoints(cam_xy: np.ndarray, facing_err: np.ndarray, grid_step: float, k: int,
                grid_id: np.ndarray | None = None) -> np.ndarray:
    """One view per grid point: the one facing the object best (indices, sorted). Grid points are
    ``grid_id`` where given, else cells of half the grid step (positions of one stop coincide)."""
    if grid_id is None:
        cell = map(tuple, np.round(cam_xy / (grid_step / 2)).astype(np.int64))
    else:
        cell = np.asarray(grid_id).tolist()
        if len(cell) != len(cam_xy):
            raise ValueError(f"grid_id has {len(cell)} entries for {len(cam_xy)} cameras")
    best: dict = {}
    for i, key in enumerate(cell):
        if key not in best or facing_err[i] < facing_err[best[key]]:
            best[key] = i
    cand = np.array(sorted(best.values()), dtype=np.int64)
    if len(cand) < k:
        raise TrackError(f"only {len(cand)} distinct viewpoints see the target; the track needs {k} "
                         "(lower evaluate.track_length or raise evaluate.max_difficulty)")
    return cand


@dataclass(frozen=True)
class TrackPlan(TrackChoice):
    start_deg: float = 0.0   # bearing (from the object) the path starts at
    direction: int = 1       # +1 counter-clockwise around the object, -1 clockwise
    distance: str = "any"    # "near" | "far" | "any": which distance band the path preferred


def select_tracks(cam_xy: np.ndarray, obj_xy: np.ndarray, facing_err: np.ndarray, k: int, n_tracks: int,
                  seed: int, *, grid_step: float = 0.3, max_arc_deg: float = 180.0,
                  grid_id: np.ndarray | None = None) -> list[TrackPlan]:
    """Up to ``n_tracks`` paths of ``k`` views, each a distinct set of views, deterministic for ``seed``.

    Track j starts at bearing ``offset + j * 360 / n_tracks`` (offset drawn from the seed), runs
    counter-clockwise for even j and clockwise for odd j, and prefers the nearer or the farther
    half of the viewpoints in turn (j // 2 even: near), which spreads the population over where
    a robot could have driven. Within its arc a path takes the view nearest each of k evenly spaced
    bearings, one per grid point (``grid_id`` per camera where given, else cells of the grid step).
    A path whose view set repeats an earlier one is moved on by a few degrees; a scan that cannot
    give ``n_tracks`` distinct paths gives fewer.
    """
    cam_xy = np.asarray(cam_xy, float)
    cand = _viewpoints(cam_xy, np.abs(np.asarray(facing_err, float)), grid_step, k, grid_id)
    rel = cam_xy[cand] - np.asarray(obj_xy, float)
    bear = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
    dist = np.hypot(*rel.T)
    spread = float(dist.max() - dist.min()) or 1.0
    rng = np.random.default_rng(seed)
    offset = float(rng.uniform(0.0, 360.0))
    out: list[TrackPlan] = []
    seen: set[frozenset] = set()
    for j in range(n_tracks):
        direction = 1 if j % 2 == 0 else -1
        band = ("near", "far")[(j // 2) % 2] if spread > grid_step else "any"
        pref = {"near": 1.0, "far": -1.0, "any": 0.0}[band] * (dist - dist.min()) / spread
        for attempt in range(24):
            start = (offset + j * 360.0 / n_tracks + attempt * 15.0) % 360.0
            b = (direction * (bear - start)) % 360.0
            arc = max_arc_deg
            inside = np.nonzero(b <= arc + 1e-9)[0]
            while len(inside) < k and arc < 360.0:  # too few viewpoints in the arc: widen it
                arc = min(360.0, arc + 30.0)
                inside = np.nonzero(b <= arc + 1e-9)[0]
            bi = b[inside]
            picked: list[int] = []
            for t in np.linspace(0.0, bi.max(), k):
                # nearest unused bearing; the distance preference (up to 20 degrees) breaks near-ties
                cost = np.abs(bi - t) + 20.0 * pref[inside]
                cost[picked] = np.inf
                picked.append(int(np.argmin(cost)))
            picked.sort(key=lambda i: bi[i])
            sel = inside[picked]
            key = frozenset(cand[sel].tolist())
            if key not in seen:
                seen.add(key)
                out.append(TrackPlan(index=cand[sel], bearing_deg=bear[sel], arc_deg=float(bi[picked].max()),
                                     start_deg=start, direction=direction, distance=band))
                break
    return out


def facing_error(cam_xy: np.ndarray, heading: np.ndarray, obj_xy: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) between each optical axis and the direction to the object."""
    rel = np.asarray(obj_xy, float) - np.asarray(cam_xy, float)
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - np.asarray(heading, float)
    return np.abs((ang + np.pi) % (2 * np.pi) - np.pi)
