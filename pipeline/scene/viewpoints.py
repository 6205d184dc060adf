"""Grid points of an AVD scan: which images were taken from the same place.

AVD's robot stops at the points of a ~30 cm grid and turns on the spot, 12 images 30 degrees apart
(docs/formats/avd.md §1.2). In real reconstructions the 12 camera centres of one stop are not one
point: two of them lie a median 3.5 cm apart (docs/formats/avd.md §3.1; the camera sits off the
turning axis and COLMAP's centres carry noise), so rounding positions cannot tell stops apart
from turns. The move graph can: images joined
by ``rotate_cw`` / ``rotate_ccw`` edges are turns on the same stop. ``grid_points`` takes the
connected components of those edges; a scan without rotate edges falls back to
``cluster_positions`` (camera centres closer than ``MERGE_RADIUS_M`` chained together).
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

ROTATE_MOVES = ("rotate_cw", "rotate_ccw")
# Chaining radius for the fallback: about 3x the median distance between two centres of one real
# stop (3.5 cm), a third of the nominal 30 cm grid step.
MERGE_RADIUS_M = 0.1


def grid_points(moves: Mapping[str, Mapping[str, str]]) -> dict[str, int]:
    """{image: grid point id} from the rotate edges of the move graph ``{image: {move: image}}``
    (targets outside ``moves`` are ignored). Ids number the components by their first image name;
    an image with no rotate edge is a grid point of its own."""
    parent = {n: n for n in moves}

    def find(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for name, mv in moves.items():
        for key in ROTATE_MOVES:
            other = mv.get(key) or ""
            if other in parent:
                a, b = find(name), find(other)
                if a != b:
                    parent[max(a, b)] = min(a, b)  # the root is the component's first name
    roots = sorted({find(n) for n in moves})
    ids = {r: i for i, r in enumerate(roots)}
    return {n: ids[find(n)] for n in moves}


def has_rotate_edges(moves: Mapping[str, Mapping[str, str]]) -> bool:
    return any((mv.get(k) or "") in moves for mv in moves.values() for k in ROTATE_MOVES)


def cluster_positions(cam_xy: np.ndarray, radius: float = MERGE_RADIUS_M) -> np.ndarray:
    """Grid point id per camera centre (n, 2): single-linkage chains of centres closer than
    ``radius``, numbered in order of their first member."""
    xy = np.asarray(cam_xy, float)
    n = len(xy)
    label = np.full(n, -1, dtype=np.int64)
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) if n else np.zeros((0, 0))
    nxt = 0
    for i in range(n):
        if label[i] >= 0:
            continue
        label[i] = nxt
        stack = [i]
        while stack:
            j = stack.pop()
            for k in np.nonzero((d[j] < radius) & (label < 0))[0]:
                label[k] = nxt
                stack.append(int(k))
        nxt += 1
    return label


def scan_grid_points(moves: Mapping[str, Mapping[str, str]], positions: Mapping[str, np.ndarray]) -> dict[str, int]:
    """{image: grid point id} for one scan: the move graph's rotate components where the scan has
    rotate edges, else the chained camera centres (``positions``: {image: (2,) metres})."""
    if has_rotate_edges(moves):
        return grid_points(moves)
    names = sorted(positions)
    labels = cluster_positions(np.array([positions[n] for n in names]).reshape(-1, 2))
    return {n: int(g) for n, g in zip(names, labels)}
