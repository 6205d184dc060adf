"""The population grid: targets x tracks x localization settings, as independent cells.

Pure functions: the evaluate stage reads the files and hands over the AVD feature rows, the model
banks and the plan; an executor (``pipeline.infra.executor``) runs ``run_cell`` on every cell. Each cell
draws its localization noise from a generator seeded by (evaluate seed, target, track, setting),
never by its position in the grid or the worker it runs on, so results do not depend on how the
grid is split or scheduled, and an ablation variant sees the same noise as the default.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.evaluation.grid import experiments as E
from pipeline.scene.location import InconsistentRays, locate
from pipeline.evaluation.grid.track import TrackPlan, select_tracks
from pipeline.scene.rays import TrackError, facing_error
from pipeline.infra import seeds
from pipeline.method.provider import calibrated, providers
from pipeline.method.score_space import of_meta, to_space
from pipeline.method.fusion import engine_device

log = logging.getLogger("viewfuse.evaluate")

DEFAULT = "default"   # the model-bank variant without an ablation override


@dataclass(frozen=True)
class Setting:
    experiment: str          # "biased" | "randomized" | "biased_randomized" | "sensitivity"
    label: str
    sigma: float
    bias: tuple[float, float]
    realizations: int
    n_x: int


PAPER_PREFIX = "paper §5.5: "   # the biased_randomized setting's label starts with it


def setting_label(sigma: float, bias) -> str:
    # ``g`` keeps every digit a user typed: sigmas 0.001 and 0.004 stay two settings.
    return f"sigma={sigma:g} m, bias=({bias[0]:+g}, {bias[1]:+g}) m"


def population_settings(ev) -> list[Setting]:
    """The settings every (target, track) runs: the biased experiment and one randomized setting
    per sigma, from the ``evaluate`` config section."""
    out = []
    if "biased" in ev.experiments:
        b = ev.biased
        out.append(Setting("biased", setting_label(b.sigma_m, b.bias_m), b.sigma_m, tuple(b.bias_m), 1,
                           b.n_loc_samples))
    if "randomized" in ev.experiments:
        r = ev.randomized
        for s in r.sigmas_m:
            out.append(Setting("randomized", setting_label(s, r.bias_m), s, tuple(r.bias_m), r.realizations,
                               r.n_loc_samples))
    if "biased_randomized" in ev.experiments:
        # The paper's §5.5 setting: a bias on every pose, then noise around the biased estimate
        # (``experiments.randomized`` draws truth + bias + N(0, sigma^2 I) per axis).
        p = ev.biased_randomized
        # its own label: the biased experiment with the same sigma and bias draws no noise, and
        # results are keyed by label
        out.append(Setting("biased_randomized", PAPER_PREFIX + setting_label(p.sigma_m, p.bias_m), p.sigma_m,
                           tuple(p.bias_m), p.realizations, p.n_loc_samples))
    labels = [s.label for s in out]
    for label in sorted({x for x in labels if labels.count(x) > 1}):
        kinds = [s.experiment for s in out if s.label == label]
        if set(kinds) == {"randomized"}:
            raise ValueError(f"evaluate.randomized.sigmas_m lists the same sigma twice ({label})")
        # results are keyed by label: a biased and a randomized setting with one sigma and bias
        # would merge
        raise ValueError(f"evaluate: the {' and '.join(kinds)} experiments both give the setting {label!r}; "
                         "change evaluate.randomized.bias_m or evaluate.biased.sigma_m")
    return out


def sensitivity_settings(ev) -> list[Setting]:
    s = ev.sensitivity
    out = [Setting("sensitivity", setting_label(sig, ev.randomized.bias_m), sig, tuple(ev.randomized.bias_m),
                   s.realizations, s.n_loc_samples) for sig in s.sigmas_m]
    if len({x.label for x in out}) != len(out):
        raise ValueError("evaluate.sensitivity.sigmas_m lists the same sigma twice")
    return out


# -- tracks ------------------------------------------------------------------------------------------
def target_views(avd: pd.DataFrame, target: str, max_difficulty: int) -> pd.DataFrame:
    """Deterministic-pass rows of the target's boxes up to ``max_difficulty``: one per (scan, image)."""
    tgt = avd[(avd["instance"] == target) & (avd["difficulty"] <= max_difficulty) & (avd["pass"] == -1)]
    return tgt.drop_duplicates(["scan", "image"])


@dataclass(frozen=True)
class TrackInfo:
    target: str
    scan: str
    track: int
    images: tuple[str, ...]
    cam_xy: np.ndarray
    heading: np.ndarray
    obj_xy: np.ndarray
    plan: TrackPlan | None = None

    def as_dict(self) -> dict:
        d = {"target": self.target, "scan": self.scan, "track": self.track, "images": list(self.images),
             "camera_xy": self.cam_xy.tolist(), "heading_rad": self.heading.tolist(),
             "object_xy_est": self.obj_xy.tolist()}
        if self.plan is not None:
            d.update(start_bearing_deg=round(self.plan.start_deg, 2), direction=self.plan.direction,
                     distance=self.plan.distance, arc_deg=round(self.plan.arc_deg, 2),
                     bearings_deg=[round(float(b), 2) for b in self.plan.bearing_deg])
        return d


class PlannedTracks(list):
    """The planned tracks (``TrackInfo``), returned with ``refused``: each scan whose rays do not
    meet, as {"target", "scan", "reason", "residual_m"}."""

    def __init__(self, tracks=(), refused: list[dict] | None = None):
        super().__init__(tracks)
        self.refused = list(refused or [])


def plan_tracks(det: pd.DataFrame, target: str, n_tracks: int, k: int, seed: int,
                intrinsics: dict[str, tuple[float, float]], grid_steps: dict[str, float],
                explicit: tuple[str, ...] = (), *, grid_points: dict[str, dict[str, int]] | None = None,
                max_residual_m: float = math.inf) -> PlannedTracks:
    """``n_tracks`` tracks of ``k`` views of one target, spread over the scans that see it (track j
    goes to the j-th scan in turn). ``explicit`` image names give exactly one track.

    ``grid_points`` ({scan: {image: grid point id}}, ``AVDScan.grid_points``) say which views share
    a stop; without them views of one stop must share a position. A scan whose rays do not meet
    (``max_residual_m``, ``pipeline.scene.location``) gives no track and is named in the result's
    ``refused``."""
    scans = sorted(det["scan"].unique())
    if not scans:
        raise TrackError(f"no AVD view of {target!r}")
    out: list[TrackInfo] = []
    refused: list[dict] = []
    if explicit:
        for scan in scans:
            d = det[det["scan"] == scan].set_index("image")
            if all(n in d.index for n in explicit):
                sel = d.loc[list(explicit)]
                obj = locate(d, *intrinsics[scan], max_residual_m).xy
                one = TrackInfo(target, scan, 0, tuple(explicit), sel[["cam_x", "cam_y"]].to_numpy(float),
                                sel["heading"].to_numpy(float), obj)
                return PlannedTracks([one])
        raise TrackError(f"evaluate.track_images: not every image has a scored box of {target!r} in one scan")
    per_scan = {s: len(range(i, n_tracks, len(scans))) for i, s in enumerate(scans)}
    errors = []
    short = 0  # tracks the scans before could not give: the next scan is asked for them too
    for scan in scans:
        want = per_scan[scan] + short
        if want == 0:
            continue
        d = det[det["scan"] == scan].reset_index(drop=True)
        short = want
        if len(d) < 2:
            errors.append(f"{scan}: {len(d)} view(s)")
            continue
        try:
            obj = locate(d, *intrinsics[scan], max_residual_m).xy
            cam = d[["cam_x", "cam_y"]].to_numpy(float)
            err = facing_error(cam, d["heading"].to_numpy(float), obj)
            gid = None if grid_points is None else view_grid_ids(d["image"], grid_points[scan], scan)
            plans = select_tracks(cam, obj, err, k, want, seed=seeds.key(seed, f"{scan}/{target}"),
                                  grid_step=grid_steps[scan], grid_id=gid)
        except TrackError as e:
            errors.append(f"{scan}: {e}")
            if isinstance(e, InconsistentRays):
                refused.append({"target": target, "scan": scan, "reason": f"{scan}: {e}",
                                "residual_m": round(e.residual_m, 4)})
            continue
        short = want - len(plans)
        for p in plans:
            sel = d.iloc[p.index]
            out.append(TrackInfo(target, scan, len(out), tuple(sel["image"]), sel[["cam_x", "cam_y"]].to_numpy(float),
                                 sel["heading"].to_numpy(float), obj, p))
    if not out:
        raise TrackError(f"no usable track of {target!r}: " + "; ".join(errors))
    return PlannedTracks(out, refused)


def view_grid_ids(images, grid: dict[str, int], scan: str) -> np.ndarray:
    """The grid point id of each image name (a name the scan's grid does not know is an error)."""
    try:
        return np.array([grid[n] for n in images], dtype=np.int64)
    except KeyError as e:
        raise TrackError(f"{scan}: image {e.args[0]!r} has no grid point in the scan read") from None


def track_samples(avd: pd.DataFrame, scores: np.ndarray, info: TrackInfo, max_difficulty: int) -> np.ndarray:
    """Whole score vectors of the dropout samples of the track's views, (K, N_s, D), in pass order."""
    rows = avd[(avd["instance"] == info.target) & (avd["scan"] == info.scan) & (avd["pass"] >= 0)
               & (avd["difficulty"] <= max_difficulty)]
    # One grouping by image instead of a filter of the rows per view (a planning world asks for
    # every view of its target: ~100 filters of Arrow strings, 0.1 s a world).
    at = rows.groupby("image", sort=False).indices
    passes, index = rows["pass"].to_numpy(), rows.index.to_numpy()
    out = []
    for name in info.images:
        pos = at.get(name)
        if pos is None:
            raise TrackError(f"view {info.scan}/{name} has no MC-dropout samples in avd.parquet")
        p = passes[pos]
        if len(np.unique(p)) == len(p):   # the view's rows in pass order (distinct passes: any sort)
            out.append(scores[index[pos[np.argsort(p, kind="stable")]]])
        else:   # a pass twice (two boxes of the target in one image): pandas' own order, as before
            out.append(scores[rows.iloc[pos].sort_values("pass").index.to_numpy()])
    if len({len(x) for x in out}) != 1:
        raise TrackError(f"the views of track {info.track} of {info.target!r} have different numbers of dropout samples")
    return np.stack(out).astype(np.float64)


# -- cells -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """One (variant, target, track): every setting runs on it. Arrays are small (K views)."""
    variant: str
    target: str
    track: int
    scan: str
    classes: tuple[str, ...]
    components: tuple[int, ...]
    truth: int
    data: E.TrackData
    settings: tuple[Setting, ...]
    seed: int
    var_floor: float
    difficulty: bool = True
    attribution: bool = False                       # add the With Uncertainty attribution variants
    test_variance: tuple[float, ...] | None = None  # δ² per component: the calibrated likelihood
    models: dict | None = None  # {provider key: the candidates' models} (pipeline.method.provider)
    tail_df: dict | None = None  # {heavy-tailed method key: ν} of the cell's fold (evaluate.likelihood_tail)
    device: str = "cpu"      # fusion engine device (pipeline.method.fusion.engine_device); auto: cuda if the worker has one


def method_rng(seed: int, target: str, track: int, method: str) -> np.random.Generator:
    """A pose-free method's own stream (e.g. a posterior cloud's subsampling): from the cell's
    identity and the method's key only (not the variant or the setting: such a method ignores
    both), so Ray and local runs draw the same points and one method's draws never move another's."""
    return seeds.stream(seed, target, track, method)


def method_streams(seed: int, target: str, track: int, setting: Setting):
    """A pose-using method's own stream in one setting, by its key (one generator per method for
    the whole setting, so its batches continue one stream): the cell's identity, the setting and the
    key; apart from the setting's localization draws, so a method that draws moves no other's numbers."""
    made: dict[str, np.random.Generator] = {}
    skey = f"{setting.experiment}/{setting.label}"

    def rng(method: str) -> np.random.Generator:
        if method not in made:
            made[method] = seeds.stream(seed, target, track, skey, method)
        return made[method]
    return rng


def pose_free_track(cell: Cell, models, provided: dict | None = None) -> tuple[E.Posteriors, dict]:
    """The pose-free methods on the cell's track, fused once (``experiments.pose_free``): their
    (K, C) log posteriors (with their seconds), repeated over every setting's realizations, and
    their extras. ``provided``: the cell's providers' models (default ``cell.models``)."""
    t = E.track_input(models, cell.data, var_floor=cell.var_floor,
                      provided=cell.models if provided is None else provided)
    return E.pose_free(t, rng=lambda key: method_rng(cell.seed, cell.target, cell.track, key))


def cell_rng(seed: int, target: str, track: int, setting: Setting) -> np.random.Generator:
    return seeds.stream(seed, target, track, f"{setting.experiment}/{setting.label}")


def run_cell(banks, cell: Cell) -> dict:
    """Every setting of one cell: {"posts": {(experiment, label): {method: log posteriors (R, K, C)}},
    "difficulty": {method: share of views that alone rank the truth first} or None, "seconds":
    {method: wall seconds in its fusion calls}, "extras": {method: the pose-free methods' extras}}."""

    with engine_device(cell.device):
        return _run_cell(banks, cell)


def cell_models(banks, cell: Cell):
    """The cell's GP models: its variant's bank at its candidates and components, with its
    test-domain variance (the calibrated likelihood) and its Student-t degrees of freedom."""
    models = banks[cell.variant].subset(cell.classes, cell.components)
    if cell.test_variance is not None:
        models = models.with_test_variance(np.asarray(cell.test_variance, float)[None, :])
    return models.with_tail_df(cell.tail_df) if cell.tail_df else models


def _run_cell(banks, cell: Cell) -> dict:
    models = cell_models(banks, cell)
    provided = calibrated(cell.models, cell.test_variance)   # the providers' models, like the bank's
    fixed, extras = pose_free_track(cell, models, provided)
    posts: dict = {}
    for s in cell.settings:
        rng = cell_rng(cell.seed, cell.target, cell.track, s)
        own = dict(var_floor=cell.var_floor, attribution=cell.attribution, fixed=fixed, provided=provided,
                   method_rng=method_streams(cell.seed, cell.target, cell.track, s))
        if s.experiment == "biased":
            posts[(s.experiment, s.label)] = E.biased(models, cell.data, s.bias, s.sigma, s.n_x, rng, **own)
        else:
            posts[(s.experiment, s.label)] = E.randomized(models, cell.data, s.bias, s.sigma, s.realizations, s.n_x,
                                                          rng, **own)
    diff = (E.single_view_first(models, cell.data, cell.truth, var_floor=cell.var_floor, provided=provided)
            if cell.difficulty else None)
    seconds = E.add_seconds(fixed.seconds, *(p.seconds for p in posts.values()))
    return {"posts": posts, "difficulty": diff, "seconds": seconds, "extras": extras}


def choose_targets(ev, avd: pd.DataFrame, plan: dict) -> list[str]:
    """The targets (``evaluate.targets``): every planned instance the scanned features show, or
    the listed ones (each must have a candidate set)."""
    seen = sorted(avd.loc[(avd["difficulty"] <= ev.max_difficulty), "instance"].unique())
    if isinstance(ev.targets, str):
        return [t for t in seen if t in plan]
    missing = [t for t in ev.targets if t not in plan]
    if missing:
        raise ValueError(f"evaluate.targets names {missing[0]!r}, for which the models stage planned no "
                         f"candidate set (modelled: {', '.join(sorted(plan))})")
    return list(ev.targets)


def build_cells(ev, avd: pd.DataFrame, scores: np.ndarray, indexes: dict, truth: dict | None,
                intr: dict, steps: dict, provided: dict | None = None, grid_points: dict | None = None,
                variant_provided: dict | None = None) -> tuple[list["Cell"], list[TrackInfo], list[dict]]:
    """Every (variant, target, track) cell of the ``evaluate`` section ``ev``: ``indexes`` maps
    variant -> its model bank's index (the plan), ``intr``/``steps``/``grid_points`` the scans'
    (fx, cx), grid steps and {image: grid point}. Targets without a usable track are skipped with
    a reason (returned), and so is each (target, scan) whose rays do not meet (with its scan and
    residual_m; the target keeps its other scans' tracks). Every cell carries the views' whole
    probability vectors and, of each provider's models in ``provided`` ({key: models},
    ``pipeline.method.provider``), those of its candidates (``ModelProvider.for_cell``).
    ``variant_provided`` ({variant: {key: models}}): a variant fitted on another training set (the
    class-level contrast's instance arm) takes its own, as it takes its own index's
    ``own_components`` (Simple Bayes' score per class) where it has them. A variant with a model
    bank of its own (its index not the default's object: a models.* ablation, the contrast's arm)
    gets no models of a provider that follows the default bank only (``default_only``; logged).
    Every variant's cell of a (target, track) shares the track, its seed and so its localization
    draws: the variants pair."""
    def for_cell(prov: dict | None, target, classes, dim) -> dict:
        mine = {}
        for key, pm in (prov or {}).items():
            try:
                mine[key] = providers()[key].for_cell(pm, target, tuple(classes), dim)
            except ValueError as e:
                raise ValueError(f"avd.parquet, target {target!r}, the {key!r} models: {e}") from None
        return mine
    plan = indexes[DEFAULT]["candidate_sets"]
    own = indexes[DEFAULT]["own_components"]
    default_only = {k for k in (provided or {}) if providers()[k].default_only}
    apart = [v for v, index in indexes.items() if index is not indexes[DEFAULT]]
    if default_only and apart:
        log.info("%s: fitted for the default model bank only; variant(s) %s have a bank of their own and run "
                 "without them (the methods that need them skip there)", ", ".join(sorted(default_only)),
                 ", ".join(apart))
    settings = tuple(population_settings(ev))
    cells, tracks, skipped = [], [], []
    for target in choose_targets(ev, avd, plan):
        det = target_views(avd, target, ev.max_difficulty)
        try:
            infos = plan_tracks(det, target, ev.tracks_per_target, ev.track_length, ev.seed, intr, steps,
                                tuple(ev.track_images), grid_points=grid_points,
                                max_residual_m=ev.max_ray_residual_m)
        except TrackError as e:  # its reason names every scan, the inconsistent ones included
            skipped.append({"target": target, "reason": str(e)})
            continue
        skipped.extend(infos.refused)  # an inconsistent scan of a target with tracks elsewhere: named too
        classes = plan[target]["classes"]
        for info in infos:
            yaw = yaw_for(target, info.scan, truth, ev.yaw_source, ev.yaw_deg, ev.targets, ev.yaws_deg)
            full = track_samples(avd, scores, info, ev.max_difficulty)
            mine = for_cell(provided, target, classes, full.shape[-1])
            for variant, index in indexes.items():
                comps = index["candidate_sets"][target]["components"]
                vmine = mine if variant not in (variant_provided or {}) else \
                    for_cell(variant_provided[variant], target, classes, full.shape[-1])
                if index is not indexes[DEFAULT]:
                    vmine = {k: m for k, m in vmine.items() if k not in default_only}
                # the GP methods measure in their bank's score space; the own scores and whole vectors stay p
                data = E.TrackData(images=info.images, cam_xy=info.cam_xy, obj_xy=info.obj_xy, yaw=yaw,
                                   dropout=to_space(full, *of_meta(index.get("meta")))[:, :, list(comps)],
                                   own=full[:, :, [index.get("own_components", own)[c] for c in classes]],
                                   probs=full)
                cells.append(Cell(variant, target, info.track, info.scan, tuple(classes), tuple(comps),
                                  classes.index(target), data, settings, ev.seed, ev.variance_floor,
                                  difficulty=variant == DEFAULT, models=vmine,
                                  attribution=ev.attribution and variant == DEFAULT))
            tracks.append(info)
    if not cells:
        raise TrackError("no target has a usable track: " + "; ".join(f"{s['target']}: {s['reason']}" for s in skipped))
    return cells, tracks, skipped


def yaw_for(target: str, scan: str, truth: dict | None, source: str, yaw_deg: float,
            targets, yaws_deg) -> float:
    """Object yaw (rad): from the synthetic ground-truth sidecar or from the config."""
    if source == "config":
        if yaws_deg:
            return math.radians(yaws_deg[list(targets).index(target)])
        return math.radians(yaw_deg)
    entry = truth_entry(truth, scan, target)
    if entry is None:
        raise ValueError(f"truth.json has no yaw for {target!r} in scan {scan} (evaluate.yaw_source = 'truth' "
                         "needs the data stage's synthetic sidecar; for real data set yaw_source = 'config')")
    return math.radians(float(entry["yaw_deg"]))


def truth_entry(truth: dict | None, scan: str, target: str) -> dict | None:
    """The synthetic sidecar's record of one instance in one scan (per-scan layout, or one layout
    shared by every scan)."""
    if not truth:
        return None
    per_scan = truth.get("scans", {}).get(scan, {}).get("instances", {})
    return per_scan.get(target) or truth.get("instances", {}).get(target)
