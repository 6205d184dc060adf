"""What one target in one scan offers a planner: the move graph, the views that see the target
(their true camera positions and recorded MC-dropout scores), the object's estimated position and
yaw, the candidate classes and the scan's fixed track from that start."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.method.geometry import relative_inputs
from pipeline.planning.graph import MoveGraph


@dataclass(frozen=True)
class World:
    target: str
    scan: str
    classes: tuple[str, ...]
    components: tuple[int, ...]
    truth: int                       # index of the target's class in ``classes``
    graph: MoveGraph
    xy: dict[str, np.ndarray]        # visible node -> (2,) true camera position (m)
    dropout: dict[str, np.ndarray]   # visible node -> (N_s, F) dropout scores at ``components``
    obj_xy: np.ndarray               # (2,) object position, estimated from the boxes' rays
    yaw: float                       # object yaw (rad)
    track: tuple[str, ...] = ()      # the existing fixed track (its first view is the start)
    test_variance: tuple[float, ...] | None = None
    provided: dict = field(default_factory=dict)   # {provider key: the candidates' models} (the cell's)

    @property
    def visible(self) -> frozenset[str]:
        return frozenset(self.xy)

    def inputs(self, positions: np.ndarray) -> np.ndarray:
        """GP inputs (unit circle, object frame) of camera positions (..., 2)."""
        return relative_inputs(positions, self.obj_xy, self.yaw, unit_circle=True)
