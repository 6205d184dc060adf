"""What a robot path through one AVD scan can use: every image as a node of the move graph (camera
position, heading, grid point, moves) and every instance located from its boxes.

``scan_paths(root, scan)`` is the one entry point (the real-imagery benchmark builds its tracks on
it): it reads the scan (metadata only where ``jpg_rgb/`` is absent), locates each instance with
the evaluate stage's own ``pipeline.scene.location.locate_all`` and names the instances it
cannot locate (too few views, parallel rays, rays that do not meet) instead of guessing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from loaders.avd import MOVES, AVDBox, AVDScan
from loaders.avd_boxes import BoxNotes
from loaders.errors import SkipLog
from pipeline.scene.location import locate_all
from pipeline.scene.rays import grid_step


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
    box_notes: BoxNotes | None = None                   # boxes kept after a repair (loaders.avd_boxes)
    n_boxes: int = 0                                    # boxes read, every difficulty


def _table(views) -> dict[str, np.ndarray]:
    """(image, box) views as the columns ``pipeline.evaluation.grid.location.locate`` reads."""
    xy = np.array([img.position for img, _ in views], float).reshape(-1, 2)
    return {"cam_x": xy[:, 0], "cam_y": xy[:, 1], "heading": np.array([img.heading for img, _ in views], float),
            "box_x0": np.array([b.x0 for _, b in views], float), "box_x1": np.array([b.x1 for _, b in views], float)}


def scan_paths(root: str | Path, scan: str, *, max_difficulty: int = 4, max_residual_m: float = 0.25,
               skip: SkipLog | None = None, frames: bool | None = None) -> ScanPaths:
    """The move graph and the located instances of one scan under ``root`` (an AVD root holding
    ``instance_id_map.txt``). ``frames=None`` reads frames where ``jpg_rgb/`` exists, metadata
    only otherwise. Boxes up to ``max_difficulty`` locate an instance; ``max_residual_m`` is
    ``evaluate.max_ray_residual_m``."""

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
    views = {inst: s.boxes_of(inst, max_difficulty)
             for inst in sorted({s.instance_names[b.instance_id] for img in s.images.values() for b in img.boxes})}
    found, excluded = locate_all(((inst, _table(v)) for inst, v in views.items()), fx, cx, max_residual_m, scan)
    located = {inst: LocatedInstance(inst, loc.xy, loc.residual_m, {img.name: b for img, b in views[inst]})
               for inst, loc in found.items()}
    return ScanPaths(scan, fx, cx, s.image_size, step, nodes, located, excluded, skip, s.box_notes,
                     sum(len(img.boxes) for img in s.images.values()))



def summary_rows(root: str | Path, max_difficulty: int = 4, max_residual_m: float = 0.25) -> tuple[list[dict], list[float]]:
    """Per scan under ``root``: what the reader read, refused and repaired, the grid, the located
    and excluded instances; and the residuals of every located instance (no limit applied)."""

    rows, residuals = [], []
    root = Path(root)
    for scan in sorted(p.name for p in root.iterdir() if (p / "annotations.json").is_file()):
        skip = SkipLog("AVD entry")
        sp = scan_paths(root, scan, max_difficulty=max_difficulty, max_residual_m=math.inf, skip=skip)
        xy = np.array([n.position for n in sp.nodes.values()])
        over = {i: loc.residual_m for i, loc in sp.instances.items() if not loc.residual_m <= max_residual_m}
        residuals += [loc.residual_m for i, loc in sp.instances.items() if i not in over]
        rows.append({"scan": scan, "images": len(sp.nodes), "boxes": sp.n_boxes, "refused": skip.count, "refusals": dict(skip.reasons),
                     "difficulty_assigned": sp.box_notes.unassigned, "clipped": sp.box_notes.clipped,
                     "grid_points": len({n.grid_point for n in sp.nodes.values()}),
                     "grid_step_positions_m": grid_step(xy), "grid_step_m": sp.grid_step_m,
                     "located": len(sp.instances) - len(over), "excluded": over})
    return rows, residuals


def main(argv: list[str] | None = None) -> None:
    """``python -m loaders.avd_paths <avd root>``: the table of ``summary_rows``."""
    import argparse

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("root")
    ap.add_argument("--max-difficulty", type=int, default=4)
    ap.add_argument("--max-residual-m", type=float, default=0.25)
    a = ap.parse_args(argv)
    rows, res = summary_rows(a.root, a.max_difficulty, a.max_residual_m)
    print("scan        images  boxes refused d0->size clipped stops step(pos) step(stops) located excluded (RMS m)")
    for r in rows:
        print(f"{r['scan']:<11} {r['images']:>6} {r['boxes']:>6} {r['refused']:>7} {r['difficulty_assigned']:>8} {r['clipped']:>7} "
              f"{r['grid_points']:>5} {r['grid_step_positions_m']:>9.4f} {r['grid_step_m']:>11.4f} {r['located']:>7} "
              + ", ".join(f"{i} {v:.2f}" for i, v in sorted(r["excluded"].items())))
    print(f"located (instance, scan) pairs: {len(res)}; ray residual (RMS) median {np.median(res) * 100:.2f} cm, "
          f"p90 {np.percentile(res, 90) * 100:.2f} cm, max {np.max(res) * 100:.2f} cm")


if __name__ == "__main__":
    main()
