"""The planning population: every target x ``plan.starts`` start nodes x the localization settings
(biased, randomized) x the planners, as independent tasks (one per target and start).

The start nodes are the first views of the target's first ``plan.starts`` fixed tracks (the
evaluate stage's tracks, spread over the scans that see it), so the fixed-track baseline starts
where the planners do. Every random draw is keyed by the task's identity (seed, target, scan,
start, setting, node or planner), never by its place in the population or the worker.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluation.grid.population import TrackInfo, track_samples
from pipeline.method.score_space import DEFAULT as DEFAULT_SPACE, DEFAULT_FLOOR, to_space
from pipeline.method.provider import calibrated
from pipeline.method.registry import REFERENCE
from pipeline.planning.belief import Belief
from pipeline.planning.eig import RingTable, standard_draws
from pipeline.planning.episode import Episode, run_episode
from pipeline.planning.graph import MoveGraph
from pipeline.planning.planners import PLANNERS, make_planner
from pipeline.planning.world import World
from pipeline.infra import seeds


@dataclass(frozen=True)
class LocSetting:
    name: str                    # "biased" | "randomized"
    bias: tuple[float, float]
    est_sigma: float             # std of the estimate's error per view
    sigma: float                 # std told to With Uncertainty (its localization samples)
    n_x: int


def loc_settings(ev, plan) -> tuple[LocSetting, ...]:
    """The biased setting of ``evaluate.biased`` and one randomized setting at ``plan.sigma_m``."""
    b, r = ev.biased, ev.randomized
    return (LocSetting("biased", tuple(b.bias_m), 0.0, b.sigma_m, b.n_loc_samples),
            LocSetting("randomized", tuple(r.bias_m), plan.sigma_m, plan.sigma_m, r.n_loc_samples))


@dataclass(frozen=True)
class Task:
    world: World
    start: int                   # index of the start among the target's starts
    settings: tuple[LocSetting, ...]
    planners: tuple[str, ...]
    budget: int
    horizon: int
    confidence: float
    eig_samples: int
    seed: int
    var_floor: float
    method: str = REFERENCE      # the registered method whose belief the robot keeps (``planning``)


def build_world(cell, info: TrackInfo, avd, scores, moves: dict, max_difficulty: int,
                space: tuple = (DEFAULT_SPACE, DEFAULT_FLOOR)) -> World:
    """The world of one default-variant cell's target in its scan: every view that sees the target
    (with its recorded dropout scores at the cell's components, in the bank's score space ``space``:
    (space, floor), ``pipeline.method.score_space``) and the move graph."""
    rows = avd[(avd["instance"] == cell.target) & (avd["scan"] == info.scan) & (avd["pass"] == -1)
               & (avd["difficulty"] <= max_difficulty)].drop_duplicates("image")
    graph = MoveGraph.from_moves(moves)
    rows = rows[rows["image"].isin(graph.moves)]
    images = tuple(sorted(rows["image"]))
    xy = rows.set_index("image").loc[list(images), ["cam_x", "cam_y"]].to_numpy(float)
    full = track_samples(avd, scores, TrackInfo(cell.target, info.scan, 0, images, xy, np.zeros(len(images)),
                                                info.obj_xy), max_difficulty)
    drop = to_space(full, *space)[:, :, list(cell.components)]
    return World(cell.target, info.scan, tuple(cell.classes), tuple(cell.components), cell.truth, graph,
                 {n: xy[i] for i, n in enumerate(images)}, {n: drop[i] for i, n in enumerate(images)},
                 np.asarray(cell.data.obj_xy, float), float(cell.data.yaw), tuple(info.images),
                 cell.test_variance, dict(cell.models or {}))


def build_tasks(cells, tracks, avd, scores, moves: dict, ev, plan,
                space: tuple = (DEFAULT_SPACE, DEFAULT_FLOOR)) -> list[Task]:
    """One task per (target, start): the default-variant cells' first ``plan.starts`` tracks;
    ``space``: the default bank's score space (``build_world``)."""
    settings = loc_settings(ev, plan)
    by_key = {(c.target, c.track): c for c in cells if c.variant == "default"}
    tasks, seen = [], {}
    for info in tracks:
        cell = by_key.get((info.target, info.track))
        i = seen.get(info.target, 0)
        if cell is None or i >= plan.starts:
            continue
        seen[info.target] = i + 1
        world = build_world(cell, info, avd, scores, moves[info.scan], ev.max_difficulty, space)
        tasks.append(Task(world, i, settings, tuple(PLANNERS), plan.budget, plan.horizon, plan.confidence,
                          plan.eig_samples, plan.seed, ev.variance_floor))
    return tasks


def models_for(banks, world: World):
    """The world's candidates and components of the default bank, with its test-domain variance."""
    models = banks["default"].subset(world.classes, world.components)
    if world.test_variance is not None:
        models = models.with_test_variance(np.asarray(world.test_variance, float)[None, :])
    return models


_TABLES: dict = {}


def ring_table(models, world: World) -> RingTable | None:
    """The models' tabulated predictive (``eig.RingTable``), made once per model set in a
    process (the starts of one target share it); None where the training inputs are not unit
    vectors (the planner then predicts with the GPs)."""
    if not all(np.allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-9) for x in models.X):
        return None
    key = models.digest()     # the models' content: another bank with the same names is another table
    if key not in _TABLES:
        if len(_TABLES) >= 8:
            _TABLES.pop(next(iter(_TABLES)))
        _TABLES[key] = RingTable(models)
    return _TABLES[key]


def run_task(banks, task: Task) -> list[tuple[str, str, Episode]]:
    """Every (setting, planner) episode of one task: [(setting name, planner, Episode)]."""
    models = models_for(banks, task.world)
    provided = calibrated(task.world.provided, task.world.test_variance)   # the methods' own models, like the bank
    eps = standard_draws(task.eig_samples, len(task.world.components), seeds.key(task.seed, "eig"))
    table = ring_table(models, task.world)
    out = []
    for s in task.settings:
        for name in task.planners:
            belief = Belief(models, task.world, bias=s.bias, est_sigma=s.est_sigma, sigma=s.sigma, n_x=s.n_x,
                            var_floor=task.var_floor, key=(task.seed, task.start, s.name), method=task.method,
                            provided=provided)
            rng = seeds.stream(task.seed, task.world.target, task.world.scan, task.start, s.name, name)
            ep = run_episode(belief, make_planner(name, eps, table), task.world.track[0], budget=task.budget,
                             confidence=task.confidence, horizon=task.horizon, rng=rng)
            out.append((s.name, name, ep))
    return out
