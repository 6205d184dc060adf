"""Where an AVD instance stands: the least-squares point of the rays through its box centres, and
whether those rays meet there at all.

The rays of one object meet within a few centimetres in real AVD reconstructions (median RMS
distance 1.7 cm over the 286 (instance, scan) pairs of the 15 real scans, boxes up to difficulty 4;
docs/results.md). They do not when the scan holds two copies of the object, or it was moved while
the robot drove: in the real Home_006_1 six instances each stand at two places about 9 m apart, and
the least-squares point between them is 2.6-3.2 m (RMS) from the rays, a place where neither copy
is. ``locate`` therefore measures the RMS distance of the rays from the point it returns and
refuses (``InconsistentRays``, a ``TrackError``) when it exceeds ``max_residual_m``
(``evaluate.max_ray_residual_m``): the instance is excluded from that scan with its residual
named, never averaged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.scene.rays import TrackError, bearing_rays, intersect_rays


class InconsistentRays(TrackError):
    """The rays through an instance's box centres do not meet at one point."""

    def __init__(self, residual_m: float, n_rays: int, max_residual_m: float):
        self.residual_m = float(residual_m)
        self.n_rays = int(n_rays)
        super().__init__(f"the {n_rays} rays through its box centres do not meet at one point: RMS distance "
                         f"{residual_m:.2f} m from their least-squares point > evaluate.max_ray_residual_m = "
                         f"{max_residual_m:g} m (a duplicated or moved object); excluded, not averaged")


@dataclass(frozen=True)
class Location:
    xy: np.ndarray      # (2,) metres, ground frame
    residual_m: float   # RMS perpendicular distance of the rays from xy
    n_rays: int


def ray_distances(origins: np.ndarray, dirs: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Perpendicular distance of each line (origin, unit direction) from ``point``."""
    r = np.asarray(origins, float) - np.asarray(point, float)
    d = np.asarray(dirs, float)
    perp = r - np.sum(r * d, axis=1)[:, None] * d
    return np.hypot(perp[:, 0], perp[:, 1])


def locate_rays(cam_xy, heading, box_cx, fx: float, cx: float, max_residual_m: float = math.inf) -> Location:
    """The object's location from its views: cameras (n, 2), headings (n,), box centre columns (n,)."""
    o, d = bearing_rays(cam_xy, heading, box_cx, fx, cx)
    xy = intersect_rays(o, d)
    residual = float(np.sqrt(np.mean(ray_distances(o, d, xy) ** 2)))
    if not residual <= max_residual_m:
        raise InconsistentRays(residual, len(o), max_residual_m)
    return Location(xy, residual, len(o))


def locate(views, fx: float, cx: float, max_residual_m: float = math.inf) -> Location:
    """The one locate: an object's location from a table of its views (a DataFrame, or a mapping
    of arrays, with columns ``cam_x``, ``cam_y``, ``heading``, ``box_x0``, ``box_x1``: the features'
    AVD rows, the real-imagery box rows, a scan's boxes): ``locate_rays`` through the centres of its
    boxes."""
    col = lambda k: np.asarray(views[k], float).reshape(-1)   # noqa: E731
    # a table keeps its own memory layout: it fixes the least-squares sums' order, so the last bits
    cam = (views[["cam_x", "cam_y"]].to_numpy(float) if hasattr(views, "to_numpy")
           else np.stack([col("cam_x"), col("cam_y")], axis=-1))
    return locate_rays(cam, col("heading"), 0.5 * (col("box_x0") + col("box_x1")), fx, cx, max_residual_m)


def locate_all(instances, fx: float, cx: float, max_residual_m: float, scan: str
               ) -> tuple[dict[str, Location], list[dict]]:
    """Every instance of one scan, from (instance, its views) pairs: {instance: ``Location``} of
    those ``locate`` places, and for each it refuses (too few views, parallel rays, rays that do
    not meet) {"instance", "scan", "reason", "residual_m"} (None where no point was fitted)."""
    located: dict[str, Location] = {}
    refused: list[dict] = []
    for inst, views in instances:
        try:
            located[inst] = locate(views, fx, cx, max_residual_m)
        except TrackError as e:
            refused.append({"instance": inst, "scan": scan, "reason": str(e),
                            "residual_m": e.residual_m if isinstance(e, InconsistentRays) else None})
    return located, refused
