"""The feature tables' column contract: (name, arrow type) of every column of a ``bigbird`` or
``avd`` table and the Parquet schema the features stage writes (``pipeline.scoring.features``) and
the reader checks (``pipeline.scoring.table_checks``).
"""
from __future__ import annotations

from typing import Any

BOX_COLS = ("box_x0", "box_y0", "box_x1", "box_y1")
CROP_COLS = ("crop_x0", "crop_y0", "crop_x1", "crop_y1")


def _fields(kind: str) -> list[tuple[str, Any]]:
    import pyarrow as pa

    i32, f64 = pa.int32(), pa.float64()
    if kind == "bigbird":
        head = [("object", pa.string()), ("camera", i32), ("angle_deg", i32), ("image", pa.string())]
        tail = [("cam_x", f64), ("cam_y", f64), ("cam_z", f64), ("u_x", f64), ("u_y", f64)]
    elif kind == "avd":
        head = [("scan", pa.string()), ("image", pa.string()), ("instance", pa.string()),
                ("instance_id", i32), ("difficulty", pa.int8())]
        tail = [("cam_x", f64), ("cam_y", f64), ("heading", f64), ("registered", pa.bool_())]
    else:
        raise ValueError(f"unknown feature table kind {kind!r} (bigbird or avd)")
    return head + [(c, i32) for c in BOX_COLS] + [(c, i32) for c in CROP_COLS] + tail


def columns(kind: str) -> list[tuple[str, Any]]:
    """(name, arrow type) of every column of a ``kind`` table but ``scores``."""
    import pyarrow as pa

    return _fields(kind) + [("pass", pa.int16())]


def schema(kind: str, dim: int, metadata: dict[str, str] | None = None):
    import pyarrow as pa

    fields = [pa.field(n, t, nullable=False) for n, t in _fields(kind)]
    fields += [pa.field("pass", pa.int16(), nullable=False),
               pa.field("scores", pa.list_(pa.field("item", pa.float32(), nullable=False), dim), nullable=False)]
    md = None if metadata is None else {k.encode(): str(v).encode() for k, v in metadata.items()}
    return pa.schema(fields, metadata=md)
