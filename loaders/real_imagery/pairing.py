"""Real AVD instances located from their real boxes, and their seeded pairing with COIL objects.

Every box of a scan (difficulty up to ``max_difficulty``) becomes a row with the real camera
position and heading; each real instance is located from the rays through its box centres
(``pipeline.scene.location.locate_all``, the track builder's own locate) and an instance
whose rays miss their point by more than ``max_ray_residual_m`` (a duplicated or moved object) is
refused with its residual, never averaged. The pairing is the synthetic part of this source: each
located instance of a scan stands for one COIL object (distinct within a scan, drawn by
``pairing_seed``; a scan with more located instances than objects leaves the extra ones out, also
drawn), and each paired object gets a yaw uniform on [0, 360) drawn by ``yaws_seed`` per (scan,
instance).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.scene.location import locate_all
from pipeline.infra import seeds


ROW_COLUMNS = ("scan", "image", "instance", "difficulty", "box_x0", "box_y0", "box_x1", "box_y1",
               "cam_x", "cam_y", "heading", "pass")


@dataclass(frozen=True)
class Pair:
    scan: str
    instance: str          # the real AVD instance name
    object_id: int         # the COIL object it stands for
    xy: tuple[float, float]  # located position, metres (ground frame)
    residual_m: float
    yaw_deg: float


def box_rows(scan, max_difficulty: int) -> pd.DataFrame:
    """One row per real box of ``scan`` (an ``AVDScan``) up to ``max_difficulty`` (ROW_COLUMNS;
    ``pass`` = -1 as the features table's deterministic rows)."""
    rows = []
    for img in scan.images.values():
        for b in img.boxes:
            if b.difficulty <= max_difficulty and b.instance_id in scan.instance_names:
                rows.append((scan.scan, img.name, scan.instance_names[b.instance_id], b.difficulty,
                             b.x0, b.y0, b.x1, b.y1, float(img.position[0]), float(img.position[1]),
                             float(img.heading), -1))
    return pd.DataFrame(rows, columns=list(ROW_COLUMNS)).sort_values(["instance", "image"], ignore_index=True)


def instance_views(rows: pd.DataFrame):
    """(instance, its rows, one per image) in instance order: what ``locate_all`` locates."""
    for inst, d in rows.groupby("instance", sort=True):
        yield inst, d.drop_duplicates("image")


def located_xy(rows: pd.DataFrame, fx: float, cx: float, max_residual_m: float, scan: str
               ) -> tuple[dict[str, tuple[np.ndarray, float]], list[dict]]:
    """The scan's instances located by the one locate (``pipeline.scene.location.locate_all``):
    {instance: (xy, RMS residual)} and the refused ones, residuals to 0.1 mm as the sidecar keeps them."""
    found, refused = locate_all(instance_views(rows), fx, cx, max_residual_m, scan)
    for r in refused:
        r["residual_m"] = None if r["residual_m"] is None else round(r["residual_m"], 4)
    return {inst: (np.asarray(f.xy, float), float(f.residual_m)) for inst, f in found.items()}, refused


def pair_scan(scan: str, located_xy: dict[str, tuple[np.ndarray, float]], objects, pairing_seed: int,
              yaws_seed: int) -> tuple[list[Pair], list[str]]:
    """The scan's pairs (sorted by instance) and the located instances left unpaired (more
    instances than objects). Deterministic for the seeds; independent of the other scans."""
    names = sorted(located_xy)
    rng = seeds.stream(pairing_seed, "pairing", scan)
    if len(names) > len(objects):
        keep = set(rng.choice(names, size=len(objects), replace=False).tolist())
        left = [n for n in names if n not in keep]
        names = [n for n in names if n in keep]
    else:
        left = []
    chosen = rng.permutation(np.asarray(sorted(objects), dtype=np.int64))[:len(names)]
    pairs = []
    for name, k in zip(names, chosen):
        xy, res = located_xy[name]
        yaw = float(seeds.stream(yaws_seed, "yaw", scan, name).uniform(0.0, 360.0))
        pairs.append(Pair(scan, name, int(k), (float(xy[0]), float(xy[1])), res, round(yaw, 6)))
    return pairs, left
