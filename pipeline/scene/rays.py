"""The geometry of a scan's views, over arrays: rays through box centres and their least-squares
meeting point, the capture grid's spacing, and how far each camera faces away from an object.
``TrackError`` is the one error of a scan whose geometry gives no usable track.
"""
from __future__ import annotations

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


def grid_step(cam_xy: np.ndarray, grid_id: np.ndarray | None = None) -> float:
    """The capture grid's spacing (m): the median distance from each grid point to its nearest
    neighbour. Without ``grid_id`` a grid point is a distinct camera position (to the mm), as in
    the synthetic scans, where the headings of a stop share one centre; with ``grid_id`` (one id
    per camera, ``pipeline.scene.viewpoints``) it is the mean centre of the cameras sharing an
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


def facing_error(cam_xy: np.ndarray, heading: np.ndarray, obj_xy: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) between each optical axis and the direction to the object."""
    rel = np.asarray(obj_xy, float) - np.asarray(cam_xy, float)
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - np.asarray(heading, float)
    return np.abs((ang + np.pi) % (2 * np.pi) - np.pi)
