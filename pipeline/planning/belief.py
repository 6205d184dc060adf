"""The robot's belief: the class posterior of a registered fusion method (With Uncertainty by
default) and its localization samples. A method with a model of its own (With Uncertainty +
instance) finds it in ``provided`` ({provider key: models}, ``TrackInput.models``); the planners'
lookahead (``pipeline.planning.eig``) predicts with ``models``.

The belief is updated by the method's own ``fuse_tracks`` (``pipeline.method.registry``: any
method that declares ``planning``) on the real scores recorded at the visited nodes; nothing of
the fusion is redone here. Pose estimates follow
the evaluate stage's settings: estimate = truth + bias + N(0, est_sigma² I) per view, and the
N_x localization samples are the estimate plus N(0, sigma² I) (sigma as told to the method).
Every random draw is keyed by (seed, target, scan, start, setting, node), never by the order of
visits, so every planner sees the same estimate at the same node and a run is reproducible on any
executor.
"""
from __future__ import annotations


import numpy as np

from pipeline.method import registry
from pipeline.method.fusion import log_prior
from pipeline.method.output_check import call_checked
from pipeline.method.provider import providers
from pipeline.planning.world import World
from pipeline.infra import seeds


class Belief:
    def __init__(self, models, world: World, *, bias=(0.0, 0.0), est_sigma: float = 0.0, sigma: float = 0.0,
                 n_x: int = 1, var_floor: float = 1e-6, key=(0,), method: str = registry.REFERENCE,
                 provided=None):
        if n_x < 1 or sigma < 0 or est_sigma < 0:
            raise ValueError(f"Belief: need n_x >= 1 and sigmas >= 0, got n_x={n_x}, sigma={sigma}, "
                             f"est_sigma={est_sigma}")
        self.method = registry.get(method)
        if self.method is None or not self.method.planning:
            able = [m.key for m in registry.methods() if m.planning]
            raise ValueError(f"Belief: method {method!r} is not a registered method that applies to planning "
                             f"(those that do: {able})")
        self.provided = dict(provided or {})
        missing = sorted(n for n in self.method.needs if n in providers() and n not in self.provided)
        if missing:
            raise ValueError(f"Belief: method {method!r} needs the models of {missing}: pass provided={{key: models}} "
                             "(the cell's models of those providers)")
        self.models, self.world = models, world
        self.bias = np.asarray(bias, float)
        self.est_sigma, self.sigma, self.n_x, self.var_floor = float(est_sigma), float(sigma), int(n_x), var_floor
        self.key = (*key, world.target, world.scan)   # (seed, names...): seeds.stream
        self.visited: list[str] = []
        self.log_post = log_prior(None, len(world.classes))
        self._draws: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    # -- poses -----------------------------------------------------------------------------------
    def _draw(self, node: str) -> tuple[np.ndarray, np.ndarray]:
        if node not in self._draws:
            rng = seeds.stream(*self.key, node)
            self._draws[node] = (rng.standard_normal(2), rng.standard_normal((self.n_x, 2)))
        return self._draws[node]

    def estimate(self, node: str) -> np.ndarray:
        """The pose estimate at a node (2,)."""
        return self.world.xy[node] + self.bias + self.est_sigma * self._draw(node)[0]

    def samples(self, node: str) -> np.ndarray:
        """The localization samples at a visited node (N_x, 2)."""
        return self.estimate(node)[None] + self.sigma * self._draw(node)[1]

    def predicted(self, nodes, *, known_pose: bool = False) -> np.ndarray:
        """Where the robot believes it would be at ``nodes`` (V, N_x, 2), before going there:
        its current samples moved by each move's nominal displacement (the graph's geometry), so
        its current pose error travels with it. ``known_pose``: the estimate alone (V, 1, 2)."""
        here = self.visited[-1]
        base = self.estimate(here)[None] if known_pose else self.samples(here)
        shift = np.stack([self.world.xy[n] - self.world.xy[here] for n in nodes])   # (V, 2)
        return base[None] + shift[:, None]

    # -- the class posterior ---------------------------------------------------------------------
    @property
    def posterior(self) -> np.ndarray:
        return np.exp(self.log_post)

    def _fuse(self, tracks: list[list[str]]) -> np.ndarray:
        """Log posteriors after the last step of each track (R, C), one engine call."""
        X = np.stack([np.stack([self.samples(n) for n in t], axis=1) for t in tracks])   # (R, N_x, K, 2)
        Z = np.stack([np.stack([self.world.dropout[n] for n in t]) for t in tracks])      # (R, K, N_s, F)
        est = np.stack([np.stack([self.estimate(n) for n in t]) for t in tracks])         # (R, K, 2)
        t = registry.TrackInput(dropout=Z, gp=self.models, estimates=est, samples=X, inputs=self.world.inputs,
                                var_floor=self.var_floor, threads=1, models=self.provided)
        # checked, time-limited and on read-only views like every method call (output_check.call_checked)
        return call_checked(self.method, "fuse_tracks", t, shape=(len(tracks), Z.shape[1], None))[:, -1]

    def update(self, node: str) -> np.ndarray:
        """Move to ``node`` and fuse its recorded scores: the new log posterior (C,)."""
        self.visited.append(node)
        self.log_post = self._fuse([self.visited])[0]
        return self.log_post

    def would_be(self, nodes) -> np.ndarray:
        """Log posteriors (V, C) after visiting each of ``nodes`` next (the belief is unchanged)."""
        return self._fuse([self.visited + [n] for n in nodes])
