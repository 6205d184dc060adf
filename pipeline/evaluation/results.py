"""Long-format result tables: one row per (..., realization, step, method), built column-wise.

``result_block`` turns a dict of log posteriors (R, K, C) per method into numpy columns with the
metrics (log10 MGR, as shown to people everywhere); ``write_results`` writes blocks as one Parquet
file with the posterior as a fixed-size list column. Both the evaluate stage and the simulation use
it, so every results file has the same columns and conventions.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pipeline.evaluation import metrics as M
from pipeline.evaluation.calibration import cell_calibration
from pipeline.infra.cache import atomic_path

LN10 = float(np.log(10.0))


def result_block(posts: Mapping[str, np.ndarray], truth_index: int, **const: Any) -> dict[str, np.ndarray]:
    """Columns for every (method, realization, step): ``const`` columns (repeated), realization,
    step, method, posterior (n, C), p_truth, log10_mgr, msde, correct."""
    cols: dict[str, list] = {}
    for method, lp in posts.items():
        lp = np.asarray(lp, float)
        R, K, C = lp.shape
        n = R * K
        part = {k: np.full(n, v, dtype=object if isinstance(v, str) else None) for k, v in const.items()}
        part.update({
            "realization": np.repeat(np.arange(R, dtype=np.int32), K),
            "step": np.tile(np.arange(K, dtype=np.int16), R),
            "method": np.full(n, method, dtype=object),
            "posterior": np.exp(lp).reshape(n, C),
            "p_truth": M.prob_truth(lp, truth_index, is_log=True).ravel(),
            "log10_mgr": M.log_mgr(lp, truth_index, is_log=True).ravel() / LN10,
            "msde": M.msde(lp, truth_index, is_log=True).ravel(),
            "correct": M.correct(lp, truth_index, is_log=True).ravel(),
        })
        for k, v in part.items():
            cols.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in cols.items()}


# Arrow types of the known columns; others are inferred.
_TYPES = {"track": "int16", "truth": "int16", "realization": "int32", "step": "int16"}


def write_results(blocks: Sequence[dict[str, np.ndarray]], path: str | Path, metadata: Mapping[str, str]) -> int:
    """Concatenate blocks (same columns) and write them as Parquet, atomically. Returns the rows."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not blocks:
        raise ValueError("write_results: no result blocks")
    names = list(blocks[0])
    arrays = []
    for name in names:
        col = np.concatenate([b[name] for b in blocks])
        if name == "posterior":
            C = col.shape[1]
            flat = pa.array(np.ascontiguousarray(col, np.float64).ravel(), pa.float64())
            arrays.append(pa.FixedSizeListArray.from_arrays(flat, C))
        elif col.dtype == object:
            arrays.append(pa.array(col.tolist(), pa.string()))
        else:
            arrays.append(pa.array(col, type=getattr(pa, _TYPES[name])() if name in _TYPES else None))
    table = pa.Table.from_arrays(arrays, names=names).replace_schema_metadata(dict(metadata))
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return table.num_rows


def cell_metrics(lp: np.ndarray, truth: int, confident_threshold: float = 0.99) -> dict[str, float]:
    """A cell's metrics over its realizations (R, K, C) of log posteriors: the population table's
    keys (``pipeline.evaluation.labels.METRICS``), MGR as log10 percentiles, and the calibration
    scalars of ``pipeline.evaluation.calibration.cell_calibration``."""
    row = M.summary_row(lp, truth, is_log=True)
    lm = M.log_mgr(lp, truth, is_log=True) / LN10
    return {
        "correct_final": row["correct_final"], "correct_overall": row["correct_overall"],
        "prob_truth_final": row["prob_truth_final"], "msde_final": row["msde_final"],
        "log10_mgr75_final": float(M.percentile(lm[:, -1], 75)),
        "log10_mgr95_final": float(M.percentile(lm[:, -1], 95)),
        "log10_mgr75_overall": float(M.percentile(lm, 75)),
        "log10_mgr95_overall": float(M.percentile(lm, 95)),
        **cell_calibration(lp, truth, confident_threshold),
    }


def metadata(**items: Any) -> dict[str, str]:
    """Parquet schema metadata: ``viewfuse.<key>`` -> string (JSON for non-strings)."""
    return {f"viewfuse.{k}": v if isinstance(v, str) else json.dumps(v) for k, v in items.items()}
