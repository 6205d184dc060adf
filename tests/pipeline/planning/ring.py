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
