"""What a robot path through one AVD scan can use: every image as a node of the move graph (camera
position, heading, grid point, moves) and every instance located from its boxes.

``scan_paths(root, scan)`` is the one entry point (the real-imagery benchmark builds its tracks on
it): it reads the scan (metadata only where ``jpg_rgb/`` is absent), locates each instance with
the evaluate stage's own ``pipeline.evaluation.location.locate_rays`` and names the instances it
cannot locate (too few views, parallel rays, rays that do not meet) instead of guessing.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from loaders.avd import MOVES, AVDBox, AVDScan
from loaders.errors import SkipLog
from pipeline.evaluation.location import InconsistentRays, locate_rays
from pipeline.evaluation.track import TrackError


@dataclass(frozen=True)
class ImageNode:
    image: str
    position: np.ndarray      # (2,) metres, ground frame (loaders.avd)
    heading: float            # radians, optical axis in the ground frame
    grid_point: int           # the stop it was taken from (AVDScan.grid_points)
    moves: dict[str, str]     # move -> image name ('' = not possible), annotations.json's graph
    registered: bool          # False: pose interpolated by the dataset's authors


@dataclass(frozen=True)
class LocatedInstance:
    instance: str
    xy: np.ndarray                   # (2,) metres: least-squares point of the rays
    residual_m: float                # RMS distance of the rays from xy
    boxes: dict[str, AVDBox]         # image name -> its box of the instance (difficulty filtered)


@dataclass
class ScanPaths:
    scan: str
    fx: float
    cx: float
    image_size: tuple[int, int]
    grid_step_m: float
    nodes: dict[str, ImageNode]
    instances: dict[str, LocatedInstance]
    excluded: list[dict] = field(default_factory=list)   # {"instance", "scan", "reason", "residual_m" | None}
    skips: SkipLog | None = None                        # the reader's counted skips


def scan_paths(root: str | Path, scan: str, *, max_difficulty: int = 4, max_residual_m: float = 0.25,
               skip: SkipLog | None = None, frames: bool | None = None) -> ScanPaths:
    """The move graph and the located instances of one scan under ``root`` (an AVD root holding
    ``instance_id_map.txt``). ``frames=None`` reads frames where ``jpg_rgb/`` exists, metadata
    only otherwise. Boxes up to ``max_difficulty`` locate an instance; ``max_residual_m`` is
    ``evaluate.max_ray_residual_m``."""
    from pipeline.evaluation.track import grid_step

    root = Path(root)
    if frames is None:
        frames = (root / scan / "jpg_rgb").is_dir()
    s = AVDScan(root, scan, skip=skip, frames=frames)
    K = s.intrinsics()
    fx, cx = float(K[0, 0]), float(K[0, 2])
    grid = s.grid_points()
    nodes = {n: ImageNode(n, img.position.copy(), img.heading, grid[n], {k: img.moves.get(k, "") for k in MOVES},
                          img.registered) for n, img in s.images.items()}
    names = sorted(nodes)
    step = grid_step(np.array([nodes[n].position for n in names]), np.array([grid[n] for n in names]))
    located: dict[str, LocatedInstance] = {}
    excluded: list[dict] = []
    for inst in sorted({s.instance_names[b.instance_id] for img in s.images.values() for b in img.boxes}):
        views = s.boxes_of(inst, max_difficulty)
        try:
            loc = locate_rays(np.array([img.position for img, _ in views]).reshape(-1, 2),
                              np.array([img.heading for img, _ in views]),
                              np.array([0.5 * (b.x0 + b.x1) for _, b in views]), fx, cx, max_residual_m)
        except TrackError as e:
            excluded.append({"instance": inst, "scan": scan, "reason": str(e),
                             "residual_m": e.residual_m if isinstance(e, InconsistentRays) else None})
            continue
        located[inst] = LocatedInstance(inst, loc.xy, loc.residual_m, {img.name: b for img, b in views})
    return ScanPaths(scan, fx, cx, s.image_size, step, nodes, located, excluded, skip)

