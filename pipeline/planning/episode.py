"""One episode: from a start node, measure, update the belief, choose the next node, until the
step budget or a confident posterior (max P >= confidence: the robot decides and stops).

Step 1 is the start node's measurement for every planner; each later step is one measurement at
the node the planner chose (reached by up to ``horizon`` moves, farther only when no view of the
target is that near); ``confidence`` None never stops. After the robot stops, or when no unvisited view is left (the fixed track
has ``evaluate.track_length`` views), the later steps keep the last posterior.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pipeline.infra.extension import ExtensionError
from pipeline.planning.belief import Belief
from pipeline.planning.graph import candidate_paths


@dataclass
class Episode:
    planner: str
    nodes: list[str]                 # the measurement node of each step taken
    paths: list[tuple[str, ...]]     # the moves before each measurement after the first (graph nodes)
    log_post: np.ndarray             # (budget, C) log posterior after every step
    measured: np.ndarray             # (budget,) bool: a measurement was taken at this step
    decision_s: list[float]          # seconds of each planning decision


def choose(planner, belief: Belief, cands: dict, rng: np.random.Generator) -> str:
    """``planner.choose``, its error or a choice that is no candidate named as the planner's
    (``ExtensionError``: kind, key, hook, cause), never an internal error."""
    try:
        nxt = planner.choose(belief, cands, rng)
    except (MemoryError, KeyboardInterrupt):
        raise
    except BaseException as e:  # noqa: BLE001 - SystemExit too: re-raised naming the planner
        raise ExtensionError.of("planner", planner.key, "choose", f"{type(e).__name__}: {e}") from e
    if not isinstance(nxt, str) or nxt not in cands:
        raise ExtensionError.of("planner", planner.key, "choose", f"returned {nxt!r:.60}, not one of the candidate "
                                f"nodes it was given ({', '.join(sorted(cands)[:5])}{', ...' if len(cands) > 5 else ''})")
    return nxt


def run_episode(belief: Belief, planner, start: str, *, budget: int, confidence: float | None, horizon: int,
                rng: np.random.Generator) -> Episode:
    world = belief.world
    C = len(world.classes)
    out = np.empty((budget, C))
    measured = np.zeros(budget, bool)
    nodes, paths, times = [start], [], []
    out[0] = belief.update(start)
    measured[0] = True
    track = list(world.track[1:])
    for k in range(1, budget):
        if confidence is not None and np.max(out[k - 1]) >= np.log(confidence):
            out[k:] = out[k - 1]
            break
        if planner.key == "fixed":
            nxt = track.pop(0) if track else None
            path = (nxt,)
        else:
            cands = candidate_paths(world.graph, nodes[-1], world.visible, set(nodes), horizon)
            nxt = None
            if cands:
                t0 = time.perf_counter()
                nxt = choose(planner, belief, cands, rng)
                times.append(time.perf_counter() - t0)
                path = cands[nxt]
        if nxt is None:
            out[k:] = out[k - 1]
            break
        nodes.append(nxt)
        paths.append(path)
        out[k] = belief.update(nxt)
        measured[k] = True
    return Episode(planner.key, nodes, paths, out, measured, times)
