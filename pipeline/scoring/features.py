"""Feature tables: score crops with the MC-dropout AlexNet and write/read the Parquet contract.

``bigbird.parquet``: one row per (object, camera, angle, pass); ``avd.parquet``: one row per
(scan, image, instance, pass). ``pass`` = -1 is the deterministic (eval-mode) pass, 0..N_s-1 the
dropout samples; ``scores`` is a fixed-size float32 list of softmax probabilities over the
classifier's D outputs. Key-value metadata: ``viewfuse.config_hash`` (sha256 of [features]),
``viewfuse.classifier_hash``, ``viewfuse.seed``, ``viewfuse.score_dim``,
``viewfuse.output_names`` (JSON list), ``viewfuse.n_samples`` (plus ``viewfuse.crop_policy``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from pipeline.infra.cache import atomic_path
from pipeline.scoring.feature_schema import CROP_COLS, schema
from pipeline.scoring.table_checks import check_finite_scores
from pipeline.scoring.table_checks import check_table, kind_of
from pipeline.scoring.classifiers import classifier
from pipeline.scoring.classifiers import card_arch
from pipeline.infra.threads import pace


def metadata(*, config_hash: str, classifier_hash: str, seed: int, output_names: list[str],
             n_samples: int, crop_policy: dict | None = None) -> dict[str, str]:
    md = {"viewfuse.config_hash": config_hash, "viewfuse.classifier_hash": classifier_hash,
          "viewfuse.seed": str(int(seed)), "viewfuse.score_dim": str(len(output_names)),
          "viewfuse.output_names": json.dumps(list(output_names)), "viewfuse.n_samples": str(int(n_samples))}
    if crop_policy is not None:
        md["viewfuse.crop_policy"] = json.dumps(crop_policy, sort_keys=True)
    return md


def build_table(kind: str, columns: dict[str, Iterable], det: np.ndarray, mc: np.ndarray | None,
                md: dict[str, str] | None = None):
    """Expand per-crop columns into rows: each crop gives its pass -1 row, then passes 0..N_s-1.

    ``det``: (n, D) deterministic scores; ``mc``: (n, N_s, D) dropout samples or None.
    """
    import pyarrow as pa

    det = np.asarray(det, dtype=np.float32)
    if det.ndim != 2:
        raise ValueError(f"deterministic scores must be (n, D), got {det.shape}")
    n, D = det.shape
    if mc is not None:
        mc = np.asarray(mc, dtype=np.float32)
        if mc.ndim != 3 or mc.shape[0] != n or mc.shape[2] != D:
            raise ValueError(f"dropout scores must be (n, N_s, D) = ({n}, N_s, {D}), got {mc.shape}")
        ns = mc.shape[1]
        scores = np.concatenate([det[:, None, :], mc], axis=1).reshape(n * (1 + ns), D)
    else:
        ns = 0
        scores = det
    check_finite_scores(kind, columns, det, mc)
    per = 1 + ns
    rep = np.repeat(np.arange(n), per)
    passes = np.tile(np.arange(-1, ns, dtype=np.int16), n)
    sch = schema(kind, D, md)
    arrays = []
    for f in sch:
        if f.name == "pass":
            arrays.append(pa.array(passes, type=f.type))
        elif f.name == "scores":
            flat = pa.array(np.ascontiguousarray(scores).reshape(-1), type=pa.float32())
            arrays.append(pa.FixedSizeListArray.from_arrays(flat, D).cast(f.type))
        else:
            if f.name not in columns:
                if n == 0:  # nothing scored (e.g. no box up to the difficulty): an empty table
                    arrays.append(pa.array([], type=f.type))
                    continue
                raise KeyError(f"{kind} feature table: column {f.name!r} missing")
            col = np.asarray(list(columns[f.name]) if not isinstance(columns[f.name], np.ndarray) else columns[f.name])
            if len(col) != n:
                raise ValueError(f"{kind} feature table: column {f.name!r} has {len(col)} values for {n} crops")
            arrays.append(pa.array(col[rep], type=f.type))
    return pa.Table.from_arrays(arrays, schema=sch)


def write_table(table, path: str | Path) -> None:
    import pyarrow.parquet as pq

    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")


def read_features_table(path: str | Path, kind: str | None = None, required: Iterable[str] = (),
                        error: Callable[[Path, str], Exception] | None = None,
                        with_scores: bool = True) -> tuple["Any", dict[str, str]]:
    """The one reader of a features Parquet: (its pyarrow table, its ``viewfuse.*`` metadata as
    strings), the file checked readable, with ``scores`` and the ``kind`` table's contract (bigbird
    or avd; default: from the file name; ``required``: the columns the caller uses,
    ``table_checks.check_table``). Problems raise ``error(path, problem)`` (default: ValueError
    naming the file; a missing file: FileNotFoundError). ``with_scores=False``: every column but
    ``scores`` (which the file must still have; ``read_scores`` streams it)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    fail = error or (lambda p, m: ValueError(f"{p}: {m}"))
    if not path.is_file():
        msg = "features file not found (run the 'features' stage)"
        raise FileNotFoundError(f"{path}: {msg}") if error is None else error(path, msg)
    try:
        if with_scores:
            table = pq.read_table(path)
            names = table.column_names
        else:
            names = pq.read_schema(path).names
            table = pq.read_table(path, columns=[n for n in names if n != "scores"])
    except (pa.ArrowInvalid, OSError) as e:
        raise fail(path, f"not a readable Parquet file ({e})") from None
    if "scores" not in names:
        raise fail(path, "missing column(s) scores")
    check_table(table, kind or kind_of(path, names), path, fail, required)
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()
            if k.decode().startswith("viewfuse.")}
    return table, meta


# rows of ``scores`` decoded at a time: reading the column whole (one row group) peaked at about
# four times its size (2.5 GB for real_full's 0.55 GB of AVD scores)
READ_ROWS = 8192


def read_scores(path: str | Path, n: int) -> np.ndarray:
    """The ``scores`` column of a features Parquet of ``n`` rows as (n, D) float32, decoded in
    batches of ``READ_ROWS`` rows into one array; ValueError naming the file for another type or
    rows without scores."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    f = pq.ParquetFile(path)
    t = f.schema_arrow.field("scores").type
    if not pa.types.is_fixed_size_list(t):
        raise ValueError(f"{path}: 'scores' is {t}, expected fixed_size_list<float32>")
    D = t.list_size
    out = np.empty((n, D), np.float32)
    a = nulls = 0
    for batch in f.iter_batches(batch_size=READ_ROWS, columns=["scores"]):
        col = batch.column(0)
        nulls += col.null_count
        if not col.null_count:
            out[a:a + len(col)] = col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), D)
        a += len(col)
    if nulls:
        raise ValueError(f"{path}: {nulls} row(s) have no scores")
    if a != n:
        raise ValueError(f"{path}: {a} rows of scores for {n} rows")
    return out


def read_features(path: str | Path, kind: str | None = None,
                  required: Iterable[str] = ()) -> tuple["Any", np.ndarray, dict[str, str]]:
    """(DataFrame of every column but ``scores`` (RangeIndex = row number), scores (n, D) float32,
    ``viewfuse.*`` metadata as strings), read by ``read_features_table`` and ``read_scores``."""
    table, meta = read_features_table(path, kind, required, with_scores=False)
    scores = read_scores(path, table.num_rows)
    D = scores.shape[1]
    if "viewfuse.score_dim" in meta and int(meta["viewfuse.score_dim"]) != D:
        raise ValueError(f"{path}: metadata score_dim {meta['viewfuse.score_dim']} != scores width {D}")
    check_scores(scores, path)
    return table.to_pandas(), scores, meta


SUM_TOLERANCE = 1e-3  # softmax rows stored as float32: sums are within ~1e-6 of 1
CHECK_ROWS = 8192     # rows checked at a time (8192 x 1000 float64: 66 MB)


def check_scores(scores: np.ndarray, path: str | Path, rows: np.ndarray | None = None) -> None:
    """Scores read from a features file must be probabilities: finite, in [0, 1], each row summing
    to 1 within ``SUM_TOLERANCE``. ValueError naming the file and the first bad row (its row number
    in the file: ``rows[i]`` when the scores are a subset of the file's rows)."""
    scores = np.asarray(scores)
    if scores.size == 0:
        return
    n = len(scores)
    finite, in_range, sums = np.empty(n, bool), np.empty(n, bool), np.empty(n)
    # in blocks of rows: a float64 copy of a full-scale table would be twice its size (1.1 GB)
    for a in range(0, n, CHECK_ROWS):
        s = scores[a:a + CHECK_ROWS].astype(np.float64)
        fin = np.isfinite(s).all(axis=1)
        finite[a:a + len(s)] = fin
        in_range[a:a + len(s)] = fin & (s >= 0).all(axis=1) & (s <= 1).all(axis=1)
        sums[a:a + len(s)] = np.where(fin, s.sum(axis=1), np.nan)
    ok = in_range & (np.abs(sums - 1.0) <= SUM_TOLERANCE)
    if ok.all():
        return
    i = int(np.flatnonzero(~ok)[0])
    row = int(rows[i]) if rows is not None else i
    if not finite[i]:
        why = "non-finite scores"
    elif not in_range[i]:
        first = scores[i].astype(np.float64)
        bad = first[(first < 0) | (first > 1)]
        why = f"a score outside [0, 1] ({bad[0]:.6g})"
    else:
        why = f"scores summing to {sums[i]:.6g}, not 1"
    raise ValueError(f"{path}: row {row} has {why} ({int((~ok).sum())} bad row(s) in all); "
                     "the features file is corrupt or was edited (rerun the 'features' stage)")


# -- scoring -----------------------------------------------------------------------------------
@dataclass
class CropJob:
    """One crop to score: the image, the object box, a key (seeds its dropout masks) and the
    per-crop table columns (everything but crop box, pass and scores)."""
    key: str
    image: np.ndarray
    box: tuple[int, int, int, int]
    columns: dict[str, Any] = field(default_factory=dict)


@dataclass
class CropBatch:
    """Crops cut where the images are (the driver), scored together by one task. ``seeds``: one
    dropout-mask seed per crop, from (features seed, crop key), so scores do not depend on which
    worker scores the batch or on how crops are batched."""
    what: str
    start: int
    crops: np.ndarray                  # uint8 (B, S, S, 3)
    seeds: list[int] | None
    n_samples: int

    @property
    def label(self) -> str:
        return f"{self.what} crops {self.start}-{self.start + len(self.crops) - 1}"


@dataclass
class ScoringModel:
    """What a scoring task needs: the classifier identity, its weights as plain arrays (sent once
    through the executor's shared payload; ``None`` when the scorer was registered in this process
    with ``register_scorer``), the input normalisation and the device to score on."""
    key: str
    num_classes: int
    dropout: float
    mean: tuple[float, ...]
    std: tuple[float, ...]
    device: str = "cpu"
    weights: dict[str, np.ndarray] | None = None
    arch: str = "alexnet"
    drop_connect: float = 0.0

    @classmethod
    def from_model(cls, model, card: dict, policy, device: str, *, with_weights: bool) -> "ScoringModel":
        w = {k: v.detach().cpu().numpy() for k, v in model.state_dict().items()} if with_weights else None
        return cls(key=f"{card['hash']}@{device}", num_classes=int(card["num_classes"]),
                   dropout=float(card["dropout"]), mean=tuple(policy.mean), std=tuple(policy.std),
                   device=device, weights=w, arch=card_arch(card),
                   drop_connect=float(card.get("drop_connect", 0.0)))


_SCORERS: dict[str, Any] = {}  # per process: the scorer built for a ScoringModel key


def register_scorer(key: str, scorer) -> None:
    """Use an already built scorer for ``key`` in this process (the local executor's route)."""
    _SCORERS.clear()
    _SCORERS[key] = scorer


def forget_scorers() -> None:
    """Drop this process's cached scorer (its weights) once a stage is done scoring."""
    _SCORERS.clear()


def _scorer(model: ScoringModel):
    sc = _SCORERS.get(model.key)
    if sc is None:
        import torch

        from pipeline.scoring.weight_files import load_into  # heavy: torch
        from pipeline.scoring.mc_dropout import MCDropoutScorer  # heavy: torch

        if model.weights is None:
            raise RuntimeError(f"no scorer registered for classifier {model.key} and no weights sent")
        entry = classifier(model.arch)
        net = entry.build(model.num_classes, model.dropout, model.drop_connect)
        load_into(net, {k: torch.from_numpy(np.array(v)) for k, v in model.weights.items()}, "object store",
                  entry.display)
        sc = MCDropoutScorer(net.eval().to(model.device), model.device, channels_last=entry.channels_last_scoring)
        register_scorer(model.key, sc)  # one classifier per worker process at a time
    return sc


def score_batch(model: ScoringModel, batch: CropBatch) -> tuple[np.ndarray, np.ndarray | None]:
    """Executor task: (det (B, D), dropout samples (B, N_s, D) or None) as float32 arrays."""
    from pipeline.scoring.crops import to_tensor  # heavy: cv2

    pace()   # the torch threads the free cores allow now (where the stage follows them)
    det, mc = _scorer(model).score(to_tensor(batch.crops, model.mean, model.std), batch.seeds, batch.n_samples)
    return det.float().cpu().numpy(), (None if mc is None else mc.float().cpu().numpy())


@dataclass
class Scored:
    columns: dict[str, list] = field(default_factory=dict)
    det: list[np.ndarray] = field(default_factory=list)
    mc: list[np.ndarray] = field(default_factory=list)

    released: int = 0   # crops whose arrays ``arrays(release=True)`` handed over
    off_image: int = 0  # crops whose crop box ran off their image (filled per the crop policy's pad)

    @property
    def n(self) -> int:
        return self.released + sum(len(d) for d in self.det)

    def arrays(self, dim: int, n_samples: int, release: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """(det (n, D), dropout samples (n, N_s, D) or None); ``release``: the batches' own arrays go
        (``n`` stays), so the scores are held once, not twice (0.55 GB each at real_full's scale)."""
        det = np.concatenate(self.det) if self.det else np.zeros((0, dim), np.float32)
        mc = (np.concatenate(self.mc) if self.mc else np.zeros((0, n_samples, dim), np.float32)) if n_samples else None
        if release:
            self.released = self.n
            self.det.clear()
            self.mc.clear()
        return det, mc


def crop_batches(jobs: Iterator[CropJob], policy, out: Scored, *, what: str, n_samples: int, seed: int,
                 batch_size: int) -> Iterator[CropBatch]:
    """Crop every job with ``policy`` into batches of ``batch_size``; each crop's table columns
    (crop box included) go to ``out`` in the same order."""
    from pipeline.scoring.mc_dropout import crop_seed  # heavy: torch

    pending: list[tuple[CropJob, np.ndarray, tuple]] = []
    start = 0

    def batch() -> CropBatch:
        nonlocal start
        b = CropBatch(what, start, np.stack([c for _, c, _ in pending]),
                      [crop_seed(seed, j.key) for j, _, _ in pending] if n_samples else None, n_samples)
        for j, _, cb in pending:
            for k, v in j.columns.items():
                out.columns.setdefault(k, []).append(v)
            for k, v in zip(CROP_COLS, cb):
                out.columns.setdefault(k, []).append(int(v))
        start += len(pending)
        pending.clear()
        return b

    for job in jobs:
        crop, cb = policy.crop(job.image, job.box)
        H, W = job.image.shape[:2]
        out.off_image += int(cb[0] < 0 or cb[1] < 0 or cb[2] > W or cb[3] > H)
        pending.append((job, crop, cb))
        if len(pending) >= batch_size:
            yield batch()
    if pending:
        yield batch()


def score_jobs(jobs: Iterator[CropJob], model: ScoringModel, policy, executor, *, what: str, n_samples: int,
               seed: int, batch_size: int, dim: int, gpu: bool = False) -> Scored:
    """Crop every job here, score the batches through ``executor`` (deterministic pass and, if
    ``n_samples``, that many dropout samples per crop, masks seeded by (seed, job.key))."""
    out = Scored()
    batches = crop_batches(jobs, policy, out, what=what, n_samples=n_samples, seed=seed, batch_size=batch_size)
    for det, mc in executor.imap(score_batch, batches, shared=model, desc=f"features: scoring {what}",
                                 unit="batch", gpu=gpu):
        if det.shape[1] != dim:
            raise ValueError(f"classifier gave {det.shape[1]} scores per crop, its card says {dim}")
        out.det.append(det)
        if mc is not None:
            out.mc.append(mc)
    return out


def viewpoint_spread(objects: np.ndarray, scores: np.ndarray, names: list[str]) -> dict:
    """Per object: how much its deterministic scores move with the viewpoint (std over views)."""
    out = {}
    for obj in sorted(set(objects)):
        s = scores[objects == obj].astype(np.float64)
        if len(s) < 2:
            continue
        std = s.std(axis=0)
        mean = s.mean(axis=0)
        top = np.argsort(mean)[::-1][:4]
        arg = s.argmax(1)
        out[obj] = {"views": int(len(s)),
                    "top_components": [names[i] for i in top],
                    "top_mean": [round(float(mean[i]), 4) for i in top],
                    "top_std": [round(float(std[i]), 4) for i in top],
                    "max_std": round(float(std.max()), 4),
                    "mean_std_top4": round(float(std[top].mean()), 4),
                    "argmax_classes_seen": int(len(np.unique(arg)))}
    return out
