"""The evaluation track: which AVD views of the target, in which order, and where the object is.

Pure functions over arrays (the evaluate stage does the I/O; where the object stands and the
scan's grid are ``pipeline.scene``):
- ``select_tracks`` picks several paths per target for the population evaluation, each K views
  at distinct grid points, roughly facing the object, spread over an arc around it and ordered by
  bearing (a path a robot could drive): different start bearings, both directions of travel, near
  and far where the scan offers both.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.scene.rays import TrackError


@dataclass(frozen=True)
class TrackChoice:
    index: np.ndarray        # indices into the candidate arrays, in path order
    bearing_deg: np.ndarray  # bearing of each chosen camera seen from the object
    arc_deg: float           # bearing span of the track


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
