"""``models`` stage: choose N_f score components and fit one GP per (class, component).

Reads ``features/bigbird.parquet`` (training views: rows with camera == models.camera and the
deterministic pass, pass == -1; GP inputs (u_x, u_y); targets = the chosen score components),
writes ``models/index.json`` + one ``<class>.npz`` per class (``pipeline.gp.GPClassModels``).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.components import choose_components
from pipeline.config import ModelsConfig, to_dict
from pipeline.gp import GPClassModels, fit_class_models

log = logging.getLogger("viewfuse.models")

REQUIRED = ("object", "camera", "angle_deg", "pass", "u_x", "u_y", "scores")


class FeaturesError(ValueError):
    """The features Parquet is missing or does not hold what the models need; names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


def read_training_views(path: str | Path, camera: int):
    """Deterministic-pass rows of one camera ring: (table columns as numpy dict, scores (n, D), meta)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise FeaturesError(path, "features file not found (run the 'features' stage)")
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as e:
        raise FeaturesError(path, f"not a readable Parquet file: {e}") from None
    missing = [c for c in REQUIRED if c not in table.column_names]
    if missing:
        raise FeaturesError(path, f"missing column(s) {', '.join(missing)}")
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()
            if k.decode().startswith("viewfuse.")}
    cam = table.column("camera").to_numpy()
    pas = table.column("pass").to_numpy()
    keep = np.nonzero((cam == camera) & (pas == -1))[0]
    table = table.take(pa.array(keep))
    cols = {c: table.column(c).to_numpy(zero_copy_only=False) for c in ("object", "angle_deg", "u_x", "u_y")}
    scores = _scores_matrix(table.column("scores"), path)
    if len(keep) and not np.all(np.isfinite(scores)):
        raise FeaturesError(path, "non-finite scores in the training views")
    return cols, scores, meta


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


def fit_from_features(path: str | Path, mcfg: ModelsConfig, *, progress: bool = True
                      ) -> tuple[GPClassModels, dict[str, Any]]:
    """The stage's pure function: features Parquet + [models] config -> fitted models, index extras."""
    path = Path(path)
    cols, scores, meta = read_training_views(path, mcfg.camera)
    objects = cols["object"].astype(str)
    present = sorted(set(objects))
    X_by, S_by, angles = [], [], {}
    for cls in mcfg.classes:
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
        X_by.append(X)
        S_by.append(scores[rows])
        angles[cls] = [int(a) for a in ang]
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
    comps, choice = choose_components(S_by, mcfg.n_components, mcfg.component_rule, mcfg.components)
    comp_names = None if names is None else [str(names[i]) for i in comps]
    models, diags = fit_class_models(
        X_by, [s[:, comps].T for s in S_by], mcfg.classes, comps, restarts=mcfg.restarts,
        amplitude_bounds=tuple(mcfg.amplitude_bounds), length_scale_bounds=tuple(mcfg.length_scale_bounds),
        noise_bounds=tuple(mcfg.noise_bounds), seed=mcfg.seed, component_names=comp_names, progress=progress)
    for d in diags:
        log.info("GP %s / %s: a=%.4g l=%.4g noise=%.3g lml=%.2f%s", d["class"], d["component_name"] or d["component"],
                 d["amplitude"], d["length_scale"], d["noise"], d["log_marginal_likelihood"],
                 f" [{'; '.join(d['at_bound'])}]" if d["at_bound"] else "")
    extra = {
        "component_choice": choice,
        "camera": mcfg.camera,
        "training_angles_deg": angles,
        "features": {"file": path.name, "rows_used": int(sum(len(x) for x in X_by)),
                     "score_dim": int(scores.shape[1]), "metadata": meta},
        "fit": {"restarts": mcfg.restarts, "amplitude_bounds": list(mcfg.amplitude_bounds),
                "length_scale_bounds": list(mcfg.length_scale_bounds),
                "noise_bounds": list(mcfg.noise_bounds), "seed": mcfg.seed},
        "config": to_dict(mcfg),
        "diagnostics": diags,
        "fits_with_warnings": sum(1 for d in diags if d["warnings"] or d["at_bound"]),
    }
    return models, extra


def run(ctx) -> str:
    mcfg: ModelsConfig = ctx.cfg.models
    models, extra = fit_from_features(ctx.input("features") / "bigbird.parquet", mcfg)
    models.save(ctx.out, extra=extra)
    ctx.extra.update({"classes": models.classes, "components": models.components,
                      "component_names": models.component_names,
                      "fits_with_warnings": extra["fits_with_warnings"]})
    names = models.component_names or [str(i) for i in models.components]
    return (f"{models.n_classes} classes x {models.n_components} components "
            f"({mcfg.component_rule}: {', '.join(names)}) fitted on {extra['features']['rows_used']} views; "
            f"{extra['fits_with_warnings']} fit(s) with warnings")
