"""Long-format result tables: one row per (..., realization, step, method), built column-wise.

``result_block`` turns a dict of log posteriors (R, K, C) per method into numpy columns with the
metrics (log10 MGR, as shown to people everywhere); ``write_results`` writes blocks as one Parquet
file with the posterior as a fixed-size list column (``ResultsWriter`` streams them into it). Both the evaluate stage and the simulation use
it, so every results file has the same columns and conventions.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from pipeline.evaluation import metrics as M
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
    if not blocks:
        raise ValueError("write_results: no result blocks")
    with ResultsWriter(path, metadata) as w:
        for b in blocks:
            w.write(b)
    return w.rows


def _arrow_table(blocks: Sequence[dict[str, np.ndarray]], metadata: Mapping[str, str]):
    import pyarrow as pa

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
    return pa.Table.from_arrays(arrays, names=names).replace_schema_metadata(dict(metadata))


class ResultsWriter:
    """``write_results`` one block at a time: blocks are buffered up to ``rows_per_group`` rows and
    written as a Parquet row group, so a stage streams its cells instead of holding every result
    row at once. Use as a context manager; the file appears (atomically) only on a clean exit.
    ``append`` is ``write``, for code that collects blocks in a list."""

    def __init__(self, path: str | Path, metadata: Mapping[str, str], rows_per_group: int = 250_000):
        self.path, self.metadata, self.rows_per_group = Path(path), dict(metadata), int(rows_per_group)
        self.rows = 0
        self._pending: list[dict[str, np.ndarray]] = []
        self._n_pending = 0
        self._writer = None
        self._schema = None
        self._ctx = None

    def __enter__(self) -> "ResultsWriter":
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        return self

    def write(self, block: dict[str, np.ndarray]) -> None:
        n = len(next(iter(block.values())))
        if self._pending and list(block) != list(self._pending[0]):
            raise ValueError(f"ResultsWriter: block columns {list(block)} differ from {list(self._pending[0])}")
        self._pending.append(block)
        self._n_pending += n
        if self._n_pending >= self.rows_per_group:
            self._flush()

    append = write

    def _flush(self) -> None:
        import pyarrow.parquet as pq

        if not self._pending:
            return
        table = _arrow_table(self._pending, self.metadata)
        if self._writer is None:
            self._schema = table.schema
            self._writer = pq.ParquetWriter(self._tmp, self._schema, compression="zstd")
        elif table.schema != self._schema:
            table = table.cast(self._schema)
        self._writer.write_table(table)
        self.rows += table.num_rows
        self._pending, self._n_pending = [], 0

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self._flush()
                if self._writer is None:
                    raise ValueError("write_results: no result blocks")
                self._writer.close()
            except BaseException as e:
                self._ctx.__exit__(type(e), e, e.__traceback__)   # removes the temporary file
                raise
            self._ctx.__exit__(None, None, None)
            return False
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - the original error is the one to report
                pass
        return self._ctx.__exit__(exc_type, exc, tb)


def cell_metrics(lp: np.ndarray, truth: int) -> dict[str, float]:
    """A cell's metrics over its realizations (R, K, C) of log posteriors: the population table's
    keys (``pipeline.evaluation.labels.METRICS``), MGR as log10 percentiles."""
    row = M.summary_row(lp, truth, is_log=True)
    lm = M.log_mgr(lp, truth, is_log=True) / LN10
    return {
        "correct_final": row["correct_final"], "correct_overall": row["correct_overall"],
        "prob_truth_final": row["prob_truth_final"], "msde_final": row["msde_final"],
        "log10_mgr75_final": float(M.percentile(lm[:, -1], 75)),
        "log10_mgr95_final": float(M.percentile(lm[:, -1], 95)),
        "log10_mgr75_overall": float(M.percentile(lm, 75)),
        "log10_mgr95_overall": float(M.percentile(lm, 95)),
    }


def metadata(**items: Any) -> dict[str, str]:
    """Parquet schema metadata: ``viewfuse.<key>`` -> string (JSON for non-strings)."""
    return {f"viewfuse.{k}": v if isinstance(v, str) else json.dumps(v) for k, v in items.items()}
