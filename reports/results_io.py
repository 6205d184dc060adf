"""Reading result tables for the reports: checked columns, viewfuse.* metadata decoded."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from loaders.errors import BadInputError


def read_result_table(path: Path, required, *, missing_hint: str = "") -> tuple[pd.DataFrame, dict[str, Any]]:
    """A results Parquet file and its ``viewfuse.*`` metadata (prefix dropped, classes parsed)."""
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise BadInputError(path, "not found" + (f"; {missing_hint}" if missing_hint else ""))
    try:
        table = pq.read_table(path)
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise BadInputError(path, f"not a readable Parquet file ({e})") from None
    missing = [c for c in required if c not in table.column_names]
    if missing:
        raise BadInputError(path, f"missing column(s) {', '.join(missing)}")
    meta: dict[str, Any] = {k.decode().removeprefix("viewfuse."): v.decode()
                            for k, v in (table.schema.metadata or {}).items() if k.startswith(b"viewfuse.")}
    if "classes" in meta:
        try:
            meta["classes"] = json.loads(meta["classes"])
        except json.JSONDecodeError:
            raise BadInputError(path, "metadata 'viewfuse.classes' is not a JSON list") from None
    return table.to_pandas(), meta
