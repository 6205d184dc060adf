"""The one reader of a run's artifacts for both reports: checked, and never running code.

Parquet, JSON and ``np.load(allow_pickle=False)`` only. Every problem is a ``BadInputError``
naming the file. MGR reaches the reports as log10 only (the ``log10_mgr`` column every results
writer writes, ``pipeline.evaluation.metrics.results``); a table without it is refused, naming the file.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import pandas as pd

from loaders.errors import BadInputError
from pipeline.infra.cache import NpzFileError, load_npz
from pipeline.infra import outputs
from pipeline.infra.outputs import MANIFEST
from pipeline.infra.outputs import path as out_path
from pipeline.evaluation.metrics.labels import ATTRIBUTION, methods
from pipeline.evaluation.metrics.spec import STEP_COLUMNS
from pipeline.method.registry import model_providers

log = logging.getLogger("viewfuse.report")

# The main report never needs the posterior vectors: leaving them unread keeps loading fast.
# Step columns added with the calibration metrics: optional, so a results file from before reads.
CALIBRATION_COLUMNS = ("nll", "confidence")
RESULT_COLUMNS = ("experiment", "setting", "sigma_m", "bias_x", "bias_y", "realization", "step",
                  "method", *(c for c in STEP_COLUMNS if c not in CALIBRATION_COLUMNS))
POPULATION_COLUMNS = ("variant", "target", "track", *CALIBRATION_COLUMNS)
GP_ARRAYS = ("grid", "raster_mean", "raster_std", "ring_theta", "ring_mean", "ring_std",
             "train_theta", "train_y")
STAGES = ("data", "classifier", "features", "models", "evaluate", "report")


def read_json(path: Path) -> Any:
    """The catalog's JSON reader (``outputs.read_json``), its problems as the reports' ``BadInputError``."""
    try:
        return outputs.read_json(path)
    except outputs.ArtifactError as e:
        raise BadInputError(e.path, e.problem) from None


def read_npz(path: Path, required: Iterable[str]) -> dict[str, np.ndarray]:
    """Arrays of an .npz (never unpickled; truncated or corrupt files named) with ``required`` present."""
    try:
        data = load_npz(path)
    except NpzFileError as e:
        raise BadInputError(path, e.problem) from None
    missing = [k for k in required if k not in data]
    if missing:
        raise BadInputError(path, f"missing array(s) {', '.join(missing)}")
    return data


def read_result_table(path: Path, required: Iterable[str], *, optional: Iterable[str] = (),
                      missing_hint: str = "") -> tuple[pd.DataFrame, dict[str, Any]]:
    """A results Parquet file (only ``required`` + present ``optional`` columns) and its
    ``viewfuse.*`` metadata (prefix dropped, classes parsed)."""
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise BadInputError(path, "not found" + (f"; {missing_hint}" if missing_hint else ""))
    try:
        schema = pq.read_schema(path)
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise BadInputError(path, f"not a readable Parquet file ({e})") from None
    have = set(schema.names)
    cols = [c for c in required if c in have]
    missing = [c for c in required if c not in have]
    if missing:
        raise BadInputError(path, f"missing column(s) {', '.join(missing)} (a run from an older version: "
                                  "rerun its stage)")
    cols += [c for c in optional if c in have and c not in cols]
    try:
        df = pq.read_table(path, columns=cols).to_pandas()
    except Exception as e:
        raise BadInputError(path, f"not a readable Parquet file ({e})") from None
    return df, _metadata(path, schema.metadata)


def _metadata(path: Path, raw) -> dict[str, Any]:
    meta: dict[str, Any] = {k.decode().removeprefix("viewfuse."): v.decode()
                            for k, v in (raw or {}).items() if k.startswith(b"viewfuse.")}
    if "classes" in meta:
        try:
            meta["classes"] = json.loads(meta["classes"])
        except json.JSONDecodeError:
            raise BadInputError(path, "metadata 'viewfuse.classes' is not a JSON list") from None
    return meta


# -- the evaluate stage's outputs --------------------------------------------------------------
@dataclass
class EvaluateOutputs:
    """What the evaluate stage left, each part None when absent."""
    results: pd.DataFrame | None = None
    meta: dict = field(default_factory=dict)
    track: dict | None = None
    gp: dict[str, np.ndarray] | None = None
    bias_maps: dict[str, np.ndarray] | None = None
    summary: dict | None = None

    @property
    def population(self) -> dict | None:
        p = (self.summary or {}).get("population")
        return p if isinstance(p, dict) else None

    @property
    def classes(self) -> list[str]:
        for src in (self.meta.get("classes"), (self.summary or {}).get("classes"),
                    (self.track or {}).get("classes")):
            if src:
                return list(src)
        if self.gp is not None and "classes" in self.gp:
            return [str(c) for c in self.gp["classes"]]
        return []

    @property
    def target(self) -> str:
        return (self.meta.get("target") or (self.summary or {}).get("target")
                or (self.track or {}).get("target") or "")

    @property
    def track_id(self) -> int | None:
        """The showcase track's number (results metadata or summary.json); None in older runs,
        whose detailed track is the target's first."""
        for src in (self.meta.get("track"), (self.summary or {}).get("track")):
            if src is not None and str(src).lstrip("-").isdigit():
                return int(src)
        return None

    def single_track(self, experiment: str) -> pd.DataFrame | None:
        """Rows of one experiment on the detailed (showcase) track: the default variant, the
        recorded target and track (older runs: the target's first track)."""
        if self.results is None:
            return None
        d = self.results[self.results["experiment"] == experiment]
        if "variant" in d:
            d = d[d["variant"] == "default"]
        if "target" in d and self.target:
            d = d[d["target"] == self.target]
        if "track" in d and len(d):
            tid = self.track_id
            d = d[d["track"] == (tid if tid is not None and (d["track"] == tid).any() else d["track"].min())]
        return d if len(d) else None


def read_results(path: Path) -> tuple[pd.DataFrame, dict]:
    df, meta = read_result_table(path, RESULT_COLUMNS, optional=POPULATION_COLUMNS)
    unknown = sorted(set(df["method"].unique()) - set(methods()) - set(ATTRIBUTION)) if len(df) else []
    if unknown:
        log.warning("%s: unknown method(s) %s are shown in grey", path, unknown)
    return df, meta


def load_evaluate(evaluate_dir: str | Path) -> EvaluateOutputs:
    """Read whatever the evaluate stage wrote; raise if it wrote nothing usable."""
    d = Path(evaluate_dir)
    if not d.is_dir():
        raise BadInputError(d, "evaluate output folder not found; run `viewfuse evaluate` first")
    out = EvaluateOutputs()
    p = {k: out_path(d, "evaluate", k) for k in ("results", "track", "summary", "gp_models", "bias_maps")}
    if p["results"].is_file():
        out.results, out.meta = read_results(p["results"])
    if p["track"].is_file():
        out.track = read_json(p["track"])
    if p["summary"].is_file():
        out.summary = read_json(p["summary"])
    if p["gp_models"].is_file():
        out.gp = read_npz(p["gp_models"], GP_ARRAYS)
        _check_gp(p["gp_models"], out.gp)
    if p["bias_maps"].is_file():
        out.bias_maps = read_npz(p["bias_maps"], ("bias_x", "bias_y", "posterior"))
        _check_bias_maps(p["bias_maps"], out.bias_maps)
    if all(v is None for v in (out.results, out.track, out.gp, out.bias_maps, out.summary)):
        raise BadInputError(d, "no evaluate outputs found (expected "
                               + ", ".join(f.name for f in p.values()) + ")")
    return out


def _check_gp(path: Path, g: dict) -> None:
    rm, G = g["raster_mean"], g["grid"].shape[0]
    if rm.ndim != 4 or rm.shape[2:] != (G, G) or g["raster_std"].shape != rm.shape:
        raise BadInputError(path, f"raster_mean/raster_std must be (C, F, {G}, {G}), got "
                                  f"{rm.shape} and {g['raster_std'].shape}")
    C, F = rm.shape[:2]
    T = g["ring_theta"].shape[0]
    for k in ("ring_mean", "ring_std"):
        if g[k].shape != (C, F, T):
            raise BadInputError(path, f"{k} must be ({C}, {F}, {T}), got {g[k].shape}")
    if g["train_theta"].ndim != 2 or g["train_theta"].shape[0] != C:
        raise BadInputError(path, f"train_theta must be ({C}, N), got {g['train_theta'].shape}")
    N = g["train_theta"].shape[1]
    if g["train_y"].shape != (C, F, N):
        raise BadInputError(path, f"train_y must be ({C}, {F}, {N}), got {g['train_y'].shape}")


def _check_bias_maps(path: Path, b: dict) -> None:
    p = b["posterior"]
    B = (b["bias_y"].shape[0], b["bias_x"].shape[0])
    if p.ndim != 4 or p.shape[2:] != B:
        raise BadInputError(path, f"posterior must be (K, C, {B[0]}, {B[1]}), got {p.shape}")


# -- the whole run ---------------------------------------------------------------------------------
@dataclass
class RunArtifacts:
    """Everything the main report reads from ``artifacts/<run>/``."""
    run_dir: Path
    evaluate: EvaluateOutputs
    index: dict | None = None          # models/index.json
    card: dict | None = None           # classifier/card.json
    manifests: dict[str, dict] = field(default_factory=dict)
    provided: dict = field(default_factory=dict)   # {provider key: models/<key>/index.json}

    def skipped(self) -> dict[str, Any]:
        """{stage: manifest["extra"]["skipped"]} for the stages that recorded skips."""
        return {s: m["extra"]["skipped"] for s, m in self.manifests.items()
                if isinstance(m.get("extra"), dict) and m["extra"].get("skipped") is not None}


def load_run(run_dir: str | Path) -> RunArtifacts:
    d = Path(run_dir)
    ev = load_evaluate(d / "evaluate")
    idx = out_path(d / "models", "models", "index")
    card = out_path(d / "classifier", "classifier", "card")
    manifests = {}
    for s in STAGES:
        p = d / s / MANIFEST
        if p.is_file():
            m = read_json(p)
            if isinstance(m, dict):
                manifests[s] = m
    return RunArtifacts(d, ev, read_json(idx) if idx.is_file() else None,
                        read_json(card) if card.is_file() else None, manifests, provided_indexes(d / "models"))


def provided_indexes(models_dir: Path) -> dict[str, dict]:
    """{provider key: its index.json} of every method's own models the run's models stage saved."""

    out = {}
    for p in model_providers():
        f = out_path(models_dir / p.key, "models", "index")
        if f.is_file():
            out[p.key] = read_json(f)
    return out


# -- the simulate stage's outputs --------------------------------------------------------------
SIM_COLUMNS = ("scenario", "realization", "step", "method",
               *(c for c in STEP_COLUMNS if c not in CALIBRATION_COLUMNS))
EXAMPLE_COLUMNS = ("scenario", "step", "component", "true_x", "true_y", "est_x", "est_y", "nominal",
                   "noised", "sigma_u2", "samples", "class_mean", "class_std", "class_mean_est")


@dataclass
class SimOutputs:
    results: pd.DataFrame
    example: pd.DataFrame
    meta: dict
    summary: dict

    @property
    def classes(self) -> list[str]:
        return list(self.meta.get("classes") or self.summary.get("classes") or [])

    @property
    def truth(self) -> int:
        return int(self.meta.get("truth", self.summary.get("truth", 0)))


def load_simulate(folder: str | Path) -> SimOutputs:
    d = Path(folder)
    hint = "run `viewfuse simulate` first"
    df, meta = read_result_table(out_path(d, "simulate", "results"), SIM_COLUMNS, missing_hint=hint)
    ex, _ = read_result_table(out_path(d, "simulate", "example"), EXAMPLE_COLUMNS, missing_hint=hint)
    sp = out_path(d, "simulate", "summary")
    return SimOutputs(df, ex, meta, read_json(sp) if sp.is_file() else {})
