"""The GP model bank of the ``models`` stage, as pure functions over the features file.

Reads ``features/bigbird.parquet`` (training views: rows with camera == models.camera; GP inputs
(u_x, u_y) from the deterministic pass, pass == -1; targets = score components, by default the mean
of the view's MC-dropout passes (pass >= 0, ``models.targets``), else the deterministic pass),
checks it (``FeaturesError`` names the file and the problem), plans each target's candidate set
and components (``pipeline.evaluation.grid.candidates``), sets the dropout noise floor where
``models.noise_floor = "dropout"``, fits every GP the plan needs (``pipeline.method.gp_fit``) and
returns the bank with its index extras (the plan, diagnostics, fit settings); and the training
views a method's own model provider fits on (``training_views``, ``pipeline.method.provider``).
"""
from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from pipeline.evaluation.grid.candidates import candidate_sets, own_components, plan_components
from pipeline.infra.config import ModelsConfig, to_dict
from pipeline.infra.outputs import name as out_name
from pipeline.method import score_space
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.provider import TrainingViews
from pipeline.scoring.features import check_scores, read_features_table

log = logging.getLogger("viewfuse.models")

# A component "varies" with the viewpoint when its training scores' std over the views exceeds this.
VARYING_STD = 0.01

REQUIRED = ("object", "camera", "angle_deg", "pass", "u_x", "u_y", "scores")


class FeaturesError(ValueError):
    """The features Parquet is missing or does not hold what the models need; names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


def assemble_classes(table, members, path: Path):
    """The rows of each class's member objects under the class's name (``members`` = {class:
    [object folders]}): a category class is the views of several objects; an object may serve
    several classes (its rows repeat), and objects of no class are left out. The object folder of
    each row stays as the column ``member``: the instance labels a bank-like model may fit on
    (``fit_from_features``' ``fit``)."""
    import pyarrow as pa

    objects = table.column("object").to_numpy(zero_copy_only=False).astype(str)
    idx, labels = [], []
    for cls in sorted(members):
        for obj in members[cls]:
            rows = np.nonzero(objects == obj)[0]
            if len(rows) == 0:
                raise FeaturesError(path, f"class {cls!r}: member object {obj!r} has no training views")
            idx.extend(rows.tolist())
            labels.extend([cls] * len(rows))
    out = table.take(pa.array(np.asarray(idx, dtype=np.int64)))
    out = out.append_column("member", out.column("object").cast(pa.string()))
    return out.set_column(out.schema.get_field_index("object"), "object", pa.array(labels, pa.string()))


def read_training_views(path: str | Path, camera: int, members=None):
    """One camera ring, from one read of the file: its deterministic-pass rows (table columns as
    numpy dict, scores (n, D)), the Parquet metadata, and its MC-dropout rows (pass >= 0) as a
    table for ``dropout_passes``; with ``members``, the rows as classes (``assemble_classes``)."""
    import pyarrow as pa

    path = Path(path)
    table, meta = read_features_table(path, "bigbird", [c for c in REQUIRED if c != "scores"], FeaturesError)
    cam = table.column("camera").to_numpy()
    pas = table.column("pass").to_numpy()
    keep = np.nonzero((cam == camera) & (pas == -1))[0]
    dropout = table.take(pa.array(np.nonzero((cam == camera) & (pas >= 0))[0]))
    table = table.take(pa.array(keep))
    if members:
        dropout = assemble_classes(dropout, members, path) if dropout.num_rows else dropout
        table = assemble_classes(table, members, path)
    cols = {c: table.column(c).to_numpy(zero_copy_only=False) for c in ("object", "angle_deg", "u_x", "u_y")}
    # A view's instance: its object folder (a class of members is several; otherwise the class itself).
    cols["member"] = (table.column("member") if members else table.column("object")).to_numpy(zero_copy_only=False)
    scores = _scores_matrix(table.column("scores"), path)
    try:
        check_scores(scores, path, np.arange(len(scores)) if members else keep)
        check_scores(_scores_matrix(dropout.column("scores"), path), path,
                     None if members else np.nonzero((cam == camera) & (pas >= 0))[0])
    except ValueError as e:
        raise FeaturesError(path, str(e).removeprefix(f"{path}: ")) from None
    return cols, scores, meta, dropout


def _scores_matrix(col, path: Path) -> np.ndarray:
    import pyarrow as pa

    arr = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    if arr.null_count:
        raise FeaturesError(path, f"{arr.null_count} row(s) have no scores")
    if pa.types.is_fixed_size_list(arr.type):
        D = arr.type.list_size
        return arr.flatten().to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(arr), D)
    rows = arr.to_pylist()  # variable-length lists: accept only if they all have the same length
    lens = {len(r) for r in rows}
    if len(lens) > 1:
        raise FeaturesError(path, f"score vectors have different lengths {sorted(lens)}")
    return np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)


def dropout_passes(table, path: str | Path) -> dict[str, dict[int, np.ndarray]]:
    """Per object and turntable angle: the MC-dropout score samples (N_s, D) of the dropout rows
    ``read_training_views`` returned; empty when the features hold no dropout passes."""
    if table.num_rows == 0:
        return {}
    scores = _scores_matrix(table.column("scores"), Path(path))
    if not np.all(np.isfinite(scores)):
        raise FeaturesError(path, "non-finite scores in the MC-dropout passes of the training views")
    objects = table.column("object").to_numpy(zero_copy_only=False).astype(str)
    angles = table.column("angle_deg").to_numpy()
    order = np.lexsort((table.column("pass").to_numpy(), angles, objects))  # independent of row order
    out: dict[str, dict[int, np.ndarray]] = {}
    for obj in np.unique(objects):
        rows = order[objects[order] == obj]
        out[str(obj)] = {int(a): scores[rows[angles[rows] == a]] for a in np.unique(angles[rows])}
    return out


def dropout_variance(passes: dict[str, dict[int, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per object: the MC-dropout variance of every score component, averaged over its views."""
    return {obj: np.mean([s.var(axis=0) for s in views.values()], axis=0) for obj, views in passes.items()}


def dropout_means(path: Path, passes: dict[str, dict[int, np.ndarray]], cls: str, angles) -> np.ndarray:
    """(N, D) mean of the dropout passes at each of a class's training angles, in that order."""
    views = passes.get(cls)
    if not views:
        raise FeaturesError(path, f"models.targets = 'dropout_mean' needs MC-dropout passes of the BigBIRD "
                                  f"views (features.bigbird_samples > 0); class {cls!r} has none")
    lack = [a for a in angles if a not in views]
    if lack:
        raise FeaturesError(path, f"class {cls!r}: no MC-dropout passes at angle(s) {lack[:5]} of the training views")
    return np.stack([views[a].mean(axis=0) for a in angles])


def dropout_noise_floor(path: Path, passes: dict[str, dict[int, np.ndarray]], pool: Sequence[str],
                        comps: Sequence[int], noise_bounds) -> np.ndarray:
    """(C, F) lower bound of each GP's noise variance: the class's MC-dropout variance of the
    component, kept inside the noise bounds (at least the lower bound, at most half the upper one,
    so the optimizer keeps room above it)."""
    var = dropout_variance(passes)
    missing = [c for c in pool if c not in var]
    if missing:
        raise FeaturesError(path, f"models.noise_floor = 'dropout' needs MC-dropout passes of the BigBIRD views "
                                  f"(features.bigbird_samples > 0); class {missing[0]!r} has none")
    floor = np.maximum(np.array([[var[c][i] for i in comps] for c in pool]), noise_bounds[0])
    return np.minimum(floor, 0.5 * noise_bounds[1])


def fit_targets(path: Path, mcfg: ModelsConfig, S_by: dict, passes: dict, angles: dict, pool):
    """The GP training targets per class (N, D) and the dropout passes in ``models.score_space``:
    each MC-dropout pass is mapped before the mean over passes, as the fusion maps each sample
    before it takes a step's mean (``pipeline.method.score_space``). The identity for 'probability'."""
    space, floor = mcfg.score_space, mcfg.score_floor
    if space == score_space.DEFAULT:
        return S_by, passes
    try:
        passes = {obj: {a: score_space.to_space(s, space, floor) for a, s in views.items()}
                  for obj, views in passes.items()}
        if mcfg.targets == "dropout_mean":
            return {cls: dropout_means(path, passes, cls, angles[cls]) for cls in pool}, passes
        return {cls: score_space.to_space(S_by[cls], space, floor) for cls in pool}, passes
    except ValueError as e:
        raise FeaturesError(path, f"models.score_space = {space!r}: {e}") from None


def _training_sets(path: Path, mcfg: ModelsConfig, members=None):
    """Per modelled class: GP inputs (N, 2), training scores (N, D) (``models.targets``), angles;
    plus output names, Parquet metadata, the dropout passes read (for the noise floor) and each
    class's mean deterministic-pass score vector (its position for ``evaluate.candidates = "hard"``)
    and each class's instance labels per training view (its object folders, ``cols["member"]``)."""
    cols, scores, meta, dropout = read_training_views(path, mcfg.camera, members)
    objects = cols["object"].astype(str)
    present = sorted(set(objects.tolist()))  # plain str: names in messages read 'coil_obj006', not np.str_(...)
    pool = present if isinstance(mcfg.classes, str) else list(mcfg.classes)
    if len(pool) < 2:
        raise FeaturesError(path, f"models need at least two classes; the features hold {len(pool)}")
    X_by, S_by, angles, means, members_by = {}, {}, {}, {}, {}
    for cls in pool:
        rows = np.nonzero(objects == cls)[0]
        if len(rows) == 0:
            raise FeaturesError(path, f"class {cls!r} (models.classes) has no training views for camera "
                                      f"{mcfg.camera}, deterministic pass; objects present: {', '.join(present) or 'none'}")
        if len(rows) < mcfg.min_views:
            raise FeaturesError(path, f"class {cls!r} has {len(rows)} training views, fewer than "
                                      f"models.min_views = {mcfg.min_views}")
        rows = rows[np.argsort(cols["angle_deg"][rows], kind="stable")]   # deterministic order
        ang = cols["angle_deg"][rows]
        if len(np.unique(ang)) != len(ang):
            raise FeaturesError(path, f"class {cls!r}: duplicate (camera {mcfg.camera}, angle) rows in the deterministic pass")
        X = np.stack([cols["u_x"][rows], cols["u_y"][rows]], axis=1).astype(np.float64)
        if not np.all(np.isfinite(X)):
            raise FeaturesError(path, f"class {cls!r}: non-finite GP inputs (u_x, u_y)")
        X_by[cls], S_by[cls], angles[cls] = X, scores[rows], [int(a) for a in ang]
        members_by[cls] = [str(m) for m in cols["member"][rows]]
        means[cls] = scores[rows].astype(np.float64).mean(axis=0)   # deterministic pass: the hard sets' positions
    passes = dropout_passes(dropout, path) if (mcfg.targets == "dropout_mean" or mcfg.noise_floor == "dropout") else {}
    if mcfg.targets == "dropout_mean":
        S_by = {cls: dropout_means(path, passes, cls, angles[cls]) for cls in pool}
    names = None
    if "viewfuse.output_names" in meta:
        try:
            names = json.loads(meta["viewfuse.output_names"])
        except json.JSONDecodeError:
            raise FeaturesError(path, "metadata 'viewfuse.output_names' is not a JSON list") from None
        if not isinstance(names, list) or len(names) != scores.shape[1]:
            raise FeaturesError(path, f"metadata 'viewfuse.output_names' lists {len(names) if isinstance(names, list) else '?'} "
                                      f"names for {scores.shape[1]} score components")
    else:
        log.warning("%s: no 'viewfuse.output_names' metadata; component names left empty", path)
    return pool, X_by, S_by, angles, names, meta, passes, means, members_by


def fit_from_features(path: str | Path, mcfg: ModelsConfig, *, targets: str | Sequence[str] = "all",
                      n_candidates: int = 4, candidates: str | Sequence[str] = "all", candidate_seed: int = 0,
                      progress: bool = True, candidate_folds: bool = False, class_members=None,
                      fit_cache: dict | None = None, route: str = "batch",
                      fit: Callable | None = None) -> tuple[GPClassModels, dict[str, Any]]:
    """The models stage's pure function: features Parquet + [models] config + the candidate plan -> one
    model bank (every modelled class x every component any candidate set uses) and index extras.

    ``targets``/``n_candidates``/``candidates``/``candidate_seed`` are the ``evaluate`` keys of the
    same names; the plan (candidate classes and components per target) goes into the index, and
    the evaluate stage takes its models from the bank with ``GPClassModels.subset``.
    ``fit_cache`` (shared by the banks of one stage run) and ``route``: ``fit_class_models``'s
    ``cache`` and ``route``.
    ``fit``: another bank's fit in place of ``fit_class_models``, with its arguments plus ``members``
    (each class's member object per training view): a model provider's bank-like model
    (``TrainingViews.fit_bank``, ``pipeline.method.provider``).
    """
    path = Path(path)
    pool, X_by, S_by, angles, names, meta, passes, means, members_by = _training_sets(path, mcfg, class_members)
    unknown = [] if isinstance(targets, str) else [t for t in targets if t not in pool]
    if unknown:
        raise ValueError(f"'evaluate.targets' names {unknown[0]!r}, which is not a modelled instance "
                         f"(modelled, from {path}: {', '.join(pool)})")
    tlist = pool if isinstance(targets, str) else list(targets)
    sets = candidate_sets(pool, tlist, n_candidates, candidates, candidate_seed, class_means=means,
                          folds=candidate_folds)
    plan = plan_components(sets, S_by, mcfg.n_components, mcfg.component_rule, mcfg.components,
                           mcfg.informative_min, per_candidate=candidates == "all")
    comps = sorted({i for p in plan.values() for i in p["components"]})
    for p in plan.values():
        p["component_names"] = None if names is None else [str(names[i]) for i in p["components"]]
    comp_names = None if names is None else [str(names[i]) for i in comps]
    # the plan above reads the probabilities; the GPs model them in models.score_space
    Y_by, passes = fit_targets(path, mcfg, S_by, passes, angles, pool)
    # the variance bounds and prior are stated for a range-1 score; in the space's units here
    amp_b, noise_b, noise_p = (score_space.variance_bounds(getattr(mcfg, k), mcfg.score_space, mcfg.score_floor)
                               for k in ("amplitude_bounds", "noise_bounds", "noise_prior"))
    floor = dropout_noise_floor(path, passes, pool, comps, noise_b) if mcfg.noise_floor == "dropout" else None
    fit, members = (fit_class_models, {}) if fit is None else (fit, {"members": [members_by[c] for c in pool]})
    models, diags = fit(
        [X_by[c] for c in pool], [Y_by[c][:, comps].T for c in pool], classes=pool, components=comps, **members,
        restarts=mcfg.restarts,
        amplitude_bounds=amp_b, length_scale_bounds=tuple(mcfg.length_scale_bounds),
        noise_bounds=noise_b, seed=mcfg.seed, component_names=comp_names, progress=progress,
        noise_floor=floor, hyperprior=mcfg.hyperprior, noise_prior=noise_p, route=route,
        cache=fit_cache)
    models.meta[score_space.META_KEY] = score_space.record(mcfg.score_space, mcfg.score_floor)
    for d in diags:
        log.debug("GP %s / %s: a=%.4g l=%.4g noise=%.3g lml=%.2f%s", d["class"], d["component_name"] or d["component"],
                  d["amplitude"], d["length_scale"], d["noise"], d["log_marginal_likelihood"],
                  f" [{'; '.join(d['at_bound'])}]" if d["at_bound"] else "")
    varying = [d for d in diags if d["train_std"] > VARYING_STD]
    extra = {
        "candidate_sets": plan,
        "own_components": own_components(S_by),
        "component_choice": next(iter(plan.values()))["choice"] if len(plan) == 1 else
        {"rule": mcfg.component_rule, "n_components": mcfg.n_components, "per_target": True,
         "per_candidate": candidates == "all"},
        "camera": mcfg.camera,
        "training_angles_deg": angles,
        "features": {"file": path.name, "rows_used": int(sum(len(x) for x in X_by.values())),
                     "score_dim": int(S_by[pool[0]].shape[1]), "metadata": meta},
        # the bounds and prior as fitted, in the space's units (the config's x variance_scale)
        "fit": {"restarts": mcfg.restarts, "amplitude_bounds": list(amp_b),
                "length_scale_bounds": list(mcfg.length_scale_bounds),
                "noise_bounds": list(noise_b), "noise_floor": mcfg.noise_floor, "seed": mcfg.seed,
                "targets": mcfg.targets, "score_space": mcfg.score_space, "score_floor": mcfg.score_floor,
                "variance_scale": score_space.variance_scale(mcfg.score_space, mcfg.score_floor),
                "hyperprior": mcfg.hyperprior, "noise_prior": list(noise_p)},
        "config": to_dict(mcfg),
        "diagnostics": diags,
        "fits_with_warnings": sum(1 for d in diags if d["warnings"] or d["at_bound"]),
        "varying_fits_at_bound": sum(1 for d in varying if d["at_bound"]),
        "varying_std_threshold": VARYING_STD,
    }
    return models, extra


def training_views(path: str | Path, camera: int, classes: Sequence[str], plan: dict | None = None,
                   class_members=None, fit_bank: Callable | None = None) -> TrainingViews:
    """The training ring as the model providers read it (``pipeline.method.provider.TrainingViews``):
    one read of the file; the dropout passes are assembled only for a provider that asks.
    ``fit_bank(fit)``: ``fit_from_features`` with the stage's settings and plan keys and ``fit``."""
    path = Path(path)
    cols, scores, _, dropout = read_training_views(path, camera, class_members)
    return TrainingViews(path=path, objects=cols["object"].astype(str), scores=scores,
                         passes=lambda: dropout_passes(dropout, path), classes=tuple(classes), plan=dict(plan or {}),
                         camera=camera, error=lambda problem: FeaturesError(path, problem), fit_bank=fit_bank)


def ablation_dir(ablation: str) -> str:
    """Folder (under models/) of one evaluate.ablations variant's model bank."""
    return out_name("models", "ablations") + "/" + re.sub(r"[^A-Za-z0-9._-]+", "-", ablation).strip("-")
