"""Does the stand-in world give GP fits that mean something? Shared by a test and a benchmark.

A fit "at a bound" whose training scores really vary over the views (std > ``VARYING_STD``) is a
fit the data could not pin down: noise at the floor makes one domain-shifted score "impossible",
a length scale at its lower bound treats view-to-view noise as signal.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

VARYING_STD = 0.01


def training_std(features_dir: Path, camera: int) -> dict[tuple[str, int], float]:
    """(object, component) -> std over the deterministic-pass training views of one camera ring."""
    t = pq.read_table(Path(features_dir) / "bigbird.parquet", columns=["object", "camera", "pass", "scores"])
    df = t.to_pandas()
    keep = (df["camera"] == camera) & (df["pass"] == -1)
    objs = df.loc[keep, "object"].to_numpy().astype(str)
    S = np.stack(df.loc[keep, "scores"].to_numpy()).astype(np.float64)
    return {(o, int(c)): float(S[objs == o, c].std()) for o in sorted(set(objs)) for c in range(S.shape[1])}


def bound_report(models_dir: Path, features_dir: Path) -> dict:
    """Every fit with its train std (the index's ``train_std`` where recorded, else computed from
    the features) and its bounds; ``varying_at_bound`` lists the fits that break the property."""
    index = json.loads((Path(models_dir) / "index.json").read_text())
    camera = int(index.get("camera", 1))
    stds = training_std(features_dir, camera)
    fits = []
    for d in index["diagnostics"]:
        std = d.get("train_std")
        if std is None:
            std = stds[(d["class"], int(d["component"]))]
        fits.append({"class": d["class"], "component": int(d["component"]),
                     "name": d.get("component_name"), "train_std": float(std), "at_bound": list(d["at_bound"]),
                     "amplitude": d["amplitude"], "length_scale": d["length_scale"], "noise": d["noise"]})
    varying = [f for f in fits if f["train_std"] > VARYING_STD]
    return {"fits": fits, "n_fits": len(fits), "n_varying": len(varying),
            "n_at_bound": sum(bool(f["at_bound"]) for f in fits),
            "varying_at_bound": [f for f in varying if f["at_bound"]]}
