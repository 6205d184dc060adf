"""Feature tables checked on read: a column missing, of another type, null, or a non-finite pose is
an error naming the file, the column, what was expected and what was found (both readers: evaluate's
``read_features`` for avd.parquet, models' ``read_training_views`` for bigbird.parquet)."""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.banks.model_bank import FeaturesError, read_training_views
from pipeline.scoring.feature_schema import columns
from pipeline.scoring.features import build_table, read_features, write_table

N, D, NS = 4, 3, 2


def _table(kind: str):
    rng = np.random.default_rng(1)
    cols = {}
    for name, t in columns(kind):
        if name == "pass":
            continue
        if pa.types.is_string(t):
            cols[name] = np.array([f"{name}_{i % 2}" for i in range(N)])
        elif pa.types.is_boolean(t):
            cols[name] = np.ones(N, bool)
        elif pa.types.is_integer(t):
            cols[name] = np.arange(N) % 2 + 1
        else:
            cols[name] = rng.uniform(-1, 1, N)
    det = rng.dirichlet(np.ones(D), N)
    mc = rng.dirichlet(np.ones(D), (N, NS))
    return build_table(kind, cols, det, mc, {"viewfuse.score_dim": str(D)})


def _write(tmp_path, kind, change=None):
    t = _table(kind)
    if change:
        t = change(t)
    path = tmp_path / f"{kind}.parquet"
    if change:
        pq.write_table(t, path)
    else:
        write_table(t, path)
    return path


def _replace(name, values):
    def change(t):
        return t.set_column(t.column_names.index(name), name, pa.array(values))
    return change


def _drop(name):
    return lambda t: t.drop_columns([name])


def _read(kind, path):
    if kind == "avd":   # as evaluate reads it
        from stages.evaluate import AVD_COLUMNS
        return read_features(path, "avd", AVD_COLUMNS)
    return read_training_views(path, camera=1)


@pytest.mark.parametrize("kind", ["avd", "bigbird"])
def test_a_table_as_the_features_stage_writes_it_reads(tmp_path, kind):
    path = _write(tmp_path, kind)
    if kind == "avd":
        df, scores, _ = read_features(path)
        assert len(df) == N * (1 + NS) and scores.shape == (N * (1 + NS), D)
    else:
        cols, scores, _, dropout = read_training_views(path, camera=1)
        assert scores.shape == (N // 2, D) and dropout.num_rows == N // 2 * NS


ROWS = N * (1 + NS)


@pytest.mark.parametrize("kind, change, message", [
    ("bigbird", _replace("camera", [str(i) for i in range(ROWS)]),
     r"column 'camera' has type string, expected int32 \(or another integer type\)"),
    ("avd", _drop("heading"), r"missing column 'heading' \(expected type double\) of the avd feature table"),
    ("avd", _drop("scan"), r"missing column 'scan' \(expected type string\)"),
    ("avd", _replace("heading", np.full(ROWS, np.nan)), r"column 'heading' has 12 non-finite value\(s\) "
                                                        r"\(first at row 0\)"),
    ("avd", _replace("pass", [str(i) for i in range(ROWS)]), r"column 'pass' has type string, expected int16"),
    ("avd", _replace("cam_x", [1.0] * (ROWS - 1) + [None]), r"column 'cam_x' has 1 null value"),
    ("bigbird", _replace("u_x", [0.0] * (ROWS - 1) + [np.inf]), r"column 'u_x' has 1 non-finite value\(s\) "
                                                                r"\(first at row 11\)"),
])
def test_a_bad_column_names_the_file_the_column_and_the_types(tmp_path, kind, change, message):
    path = _write(tmp_path, kind, change)
    with pytest.raises((ValueError, FeaturesError), match=rf"{kind}.parquet: {message}"):
        _read(kind, path)


def test_integer_poses_are_accepted_as_floats(tmp_path):
    path = _write(tmp_path, "avd", _replace("heading", list(range(ROWS))))
    df, _, _ = read_features(path)
    assert df["heading"].tolist() == list(range(ROWS))


def test_released_batches_give_the_same_arrays_and_keep_their_count():
    from pipeline.scoring.features import Scored

    rng = np.random.default_rng(3)
    det = [rng.random((b, 4), dtype=np.float32) for b in (3, 2)]
    mc = [rng.random((b, 5, 4), dtype=np.float32) for b in (3, 2)]
    kept, released = Scored(det=list(det), mc=list(mc)), Scored(det=list(det), mc=list(mc))
    d0, m0 = kept.arrays(4, 5)
    d1, m1 = released.arrays(4, 5, release=True)
    assert np.array_equal(d0, d1) and np.array_equal(m0, m1)
    assert released.det == [] and released.mc == [] and released.n == kept.n == 5
    assert Scored(det=list(det)).arrays(4, 0, release=True)[1] is None


def test_scores_are_read_in_batches_across_row_groups(tmp_path, monkeypatch):
    from pipeline.scoring import features as F

    t = _table("avd")                                   # N crops x (1 + NS) passes = 12 rows
    path = tmp_path / "avd.parquet"
    pq.write_table(t, path, row_group_size=5)           # batches that straddle the row groups
    monkeypatch.setattr(F, "READ_ROWS", 4)
    df, scores, meta = read_features(path, "avd")
    whole = t.column("scores").combine_chunks()
    assert np.array_equal(scores, whole.flatten().to_numpy().reshape(len(t), D))
    assert scores.dtype == np.float32 and len(df) == len(t) and "scores" not in df.columns
    assert meta["viewfuse.score_dim"] == str(D)
    with pytest.raises(ValueError, match=r"avd.parquet: 12 rows of scores for 13 rows"):
        F.read_scores(path, 13)
    i = t.schema.get_field_index("scores")
    holes = pa.array([None if r in (2, 9) else v for r, v in enumerate(whole.to_pylist())], whole.type)
    pq.write_table(t.set_column(i, pa.field("scores", whole.type), holes), path, row_group_size=5)
    with pytest.raises(ValueError, match=r"avd.parquet: 2 row\(s\) have no scores"):
        read_features(path, "avd")
