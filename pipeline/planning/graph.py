"""The AVD move graph of one scan and what one target shows on it.

Nodes are image names; ``annotations.json`` links each image to the image a move reaches
(``rotate_cw``, ``rotate_ccw``, ``forward``, ``backward``, ``left``, ``right``; '' = no such move).
A node *sees* the target when the features stage scored a box of it there (difficulty filtered):
only there does a step give a measurement.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

MOVES = ("rotate_cw", "rotate_ccw", "forward", "backward", "left", "right")


@dataclass(frozen=True)
class MoveGraph:
    """``moves``: {image: {move: image}} of one scan (moves to unknown images are dropped)."""
    moves: Mapping[str, Mapping[str, str]]

    def __post_init__(self):
        # Each node's neighbours, listed once: an episode's breadth-first searches ask for them
        # hundreds of thousands of times in the default run.
        object.__setattr__(self, "_near", {})

    @classmethod
    def from_moves(cls, moves: Mapping[str, Mapping[str, str]]) -> MoveGraph:
        nodes = set(moves)
        return cls({n: {m: t for m, t in (moves[n] or {}).items() if m in MOVES and t and t in nodes}
                    for n in sorted(nodes)})

    def neighbours(self, node: str) -> list[str]:
        """Nodes one move away, in move order, each once."""
        return list(self._adjacent(node))

    def _adjacent(self, node: str) -> tuple[str, ...]:
        near = self._near.get(node)
        if near is None:
            out = []
            for m in MOVES:
                t = self.moves.get(node, {}).get(m)
                if t and t != node and t not in out:
                    out.append(t)
            near = self._near[node] = tuple(out)
        return near

    def linked(self, a: str, b: str) -> bool:
        return b in self._adjacent(a)

    def paths(self, start: str, horizon: int | None = None) -> dict[str, tuple[str, ...]]:
        """{node: shortest move path from ``start`` (start excluded)} for every node within
        ``horizon`` moves (None: every reachable node); breadth first, ties by move order."""
        out: dict[str, tuple[str, ...]] = {start: ()}
        queue = deque([start])
        while queue:
            n = queue.popleft()
            if horizon is not None and len(out[n]) >= horizon:
                continue
            for t in self._adjacent(n):
                if t not in out:
                    out[t] = out[n] + (t,)
                    queue.append(t)
        del out[start]
        return out


def candidate_paths(graph: MoveGraph, node: str, visible, visited, horizon: int) -> dict[str, tuple[str, ...]]:
    """Where the next measurement can be taken: unvisited nodes that see the target within
    ``horizon`` moves; when there is none, the nearest such nodes at any distance (the robot
    travels on through views without the target). {} when no unvisited view is reachable."""
    near = {n: p for n, p in graph.paths(node, horizon).items() if n in visible and n not in visited}
    if near:
        return near
    far = {n: p for n, p in graph.paths(node).items() if n in visible and n not in visited}
    if not far:
        return {}
    d = min(len(p) for p in far.values())
    return {n: p for n, p in far.items() if len(p) == d}
