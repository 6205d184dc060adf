"""The feature tables' columns checked on read: every column of the contract present, of the type
family the writer uses, without nulls, the pose columns finite. A file edited or written by another
tool is then an error naming the file, the column, what was expected and what was found, not a
confusing failure later ("models need at least two classes", "SVD did not converge")."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.scoring import feature_schema

# Pose columns: a NaN heading or camera position has no meaning downstream (angles, SVD frames).
POSE_COLS = {"bigbird": ("cam_x", "cam_y", "cam_z", "u_x", "u_y"), "avd": ("cam_x", "cam_y", "heading")}


def _family(t) -> str:
    import pyarrow as pa

    if pa.types.is_boolean(t):
        return "boolean"
    if pa.types.is_integer(t):
        return "integer"
    if pa.types.is_floating(t):
        return "float"
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return "string"
    return str(t)


def kind_of(path: str | Path, names: list[str]) -> str:
    """bigbird or avd: from the file name the features stage gives it, else from its columns."""
    stem = Path(path).stem
    if stem in POSE_COLS:
        return stem
    return "bigbird" if "object" in names else "avd"


def check_table(table, kind: str, path: str | Path, error: Callable[[str, str], Exception],
                required: Iterable[str] = ()) -> None:
    """Raise ``error(path, problem)`` for the first column of ``table`` that breaks the ``kind``
    feature-table contract (``pipeline.scoring.feature_schema``): one of ``required`` (the
    columns the reader uses) missing, or a contract column present but of another type, null,
    or (a pose) not finite."""
    contract = dict(feature_schema.columns(kind))
    for name in required:
        if name not in table.column_names:
            t = contract[name]
            raise error(path, f"missing column '{name}' (expected type {t}) of the {kind} feature table")
    for name, t in contract.items():
        if name not in table.column_names:
            continue
        want, col = _family(t), table.column(name)
        got = _family(col.type)
        # integers may stand in for floats (a pose written as whole numbers); nothing else converts
        if got != want and not (want == "float" and got == "integer"):
            raise error(path, f"column '{name}' has type {col.type}, expected {t} (or another {want} type)")
        if col.null_count:
            raise error(path, f"column '{name}' has {col.null_count} null value(s); expected none")
    for name in POSE_COLS[kind]:
        if name not in table.column_names:
            continue
        v = table.column(name).to_numpy().astype(np.float64)
        bad = ~np.isfinite(v)
        if bad.any():
            raise error(path, f"column '{name}' has {int(bad.sum())} non-finite value(s) (first at row "
                              f"{int(np.flatnonzero(bad)[0])}); a pose must be finite (rerun the 'features' stage)")


# Columns that name a crop's view in an error (the image it came from and the object in it).
VIEW_COLS = {"bigbird": ("object", "camera", "angle_deg", "image"), "avd": ("scan", "image", "instance")}


def check_finite_scores(kind: str, columns: dict, det: np.ndarray, mc: np.ndarray | None) -> None:
    """ValueError naming the first view whose deterministic or dropout scores are not finite, before
    a feature table is built: a stage never writes NaN scores for a later stage to trip on."""
    bad = ~np.isfinite(det).all(axis=1)
    if mc is not None and mc.size:
        bad |= ~np.isfinite(mc).all(axis=(1, 2))
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    view = ", ".join(f"{c} {list(columns[c])[i]!r}" for c in VIEW_COLS[kind] if c in columns)
    raise ValueError(f"{kind} features: non-finite scores for {int(bad.sum())} of {len(det)} crop(s), the first "
                     f"at {view or f'crop {i}'}; the classifier's weights or input are broken, nothing written")
