"""A hand-built two-class world: views on a ring around the object, one GP component, and
exactly one view (at 180 degrees) where the two classes' scores differ."""
from __future__ import annotations

import numpy as np

from pipeline.method.gp import GPClassModels
from pipeline.planning.graph import MoveGraph
from pipeline.planning.world import World

N_NODES = 8
SEPARATING = "v4"        # the view at 180 degrees


def models(bump: float = 0.4) -> GPClassModels:
    th = np.linspace(-np.pi, np.pi, 72, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], -1)
    d = np.angle(np.exp(1j * (th - np.pi)))
    a = 0.5 + bump * np.exp(-d ** 2 / (2 * 0.25 ** 2))
    b = np.full_like(th, 0.5)
    return GPClassModels(["a", "b"], [0], [X, X], [a[None], b[None]], mean=[[0.5], [0.5]],
                         amplitude=[[0.05], [0.01]], length_scale=[[0.3], [1.0]], noise=[[1e-3], [1e-3]])


def ring_world(truth: int = 0, radius: float = 1.5, seed: int = 0, chords: bool = False) -> World:
    """Nodes v0..v7 at 0, 45, ..., 315 degrees; left/right move along the ring (with ``chords``,
    forward/backward also jump three nodes). The recorded scores follow the true class."""
    rng = np.random.default_rng(seed)
    names = [f"v{i}" for i in range(N_NODES)]
    moves = {}
    for i, n in enumerate(names):
        m = {"left": names[(i + 1) % N_NODES], "right": names[(i - 1) % N_NODES]}
        if chords:
            m.update(forward=names[(i + 3) % N_NODES], backward=names[(i - 3) % N_NODES])
        moves[n] = m
    th = np.arange(N_NODES) * 2 * np.pi / N_NODES
    xy = {n: radius * np.array([np.cos(t), np.sin(t)]) for n, t in zip(names, th)}
    high = 0.9 if truth == 0 else 0.5
    drop = {n: (high if n == SEPARATING else 0.5) + 0.01 * rng.standard_normal((5, 1)) for n in names}
    return World("obj", "scan", ("a", "b"), (0,), truth, MoveGraph.from_moves(moves), xy, drop,
                 np.zeros(2), 0.0, tuple(names[:4]))


def grid_world(models_c: int = 4, n_components: int = 4, n_s: int = 10, spacing: float = 0.3, half: int = 3,
               seed: int = 0) -> World:
    """An AVD-like scan: stops on a (2·half+1)² grid around the object (none within 0.4 m), 12
    headings per stop (rotate_cw/ccw), forward/backward/left/right between neighbouring stops for
    the four axis headings; a view sees the object within 30 degrees of its heading."""
    rng = np.random.default_rng(seed)
    stops = [(i, j) for i in range(-half, half + 1) for j in range(-half, half + 1)
             if np.hypot(i, j) * spacing > 0.4]
    have = set(stops)
    axis = {0: (1, 0), 3: (0, 1), 6: (-1, 0), 9: (0, -1)}
    moves, xy, drop = {}, {}, {}
    for (i, j) in stops:
        for h in range(12):
            m = {"rotate_ccw": f"s{i}_{j}_h{(h + 1) % 12}", "rotate_cw": f"s{i}_{j}_h{(h - 1) % 12}"}
            if h in axis:
                dx, dy = axis[h]
                for move, (a, b) in {"forward": (dx, dy), "backward": (-dx, -dy), "left": (-dy, dx),
                                     "right": (dy, -dx)}.items():
                    if (i + a, j + b) in have:
                        m[move] = f"s{i + a}_{j + b}_h{h}"
            name = f"s{i}_{j}_h{h}"
            moves[name] = m
            p = spacing * np.array([i, j], float)
            bearing = np.arctan2(-p[1], -p[0])
            if abs(np.angle(np.exp(1j * (bearing - h * np.pi / 6)))) <= np.pi / 6 + 1e-9:
                xy[name] = p
                drop[name] = 0.25 + 0.05 * rng.standard_normal((n_s, n_components))
    classes = tuple(f"c{c}" for c in range(models_c))
    first = min(xy)
    return World("obj", "scan", classes, tuple(range(n_components)), 0, MoveGraph.from_moves(moves), xy, drop,
                 np.zeros(2), 0.3, (first,))
