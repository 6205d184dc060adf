"""Caches that a restored mtime cannot fool: a stage about to use an upstream output checks its
sha256 against the manifest (each file hashed once per run), and ``viewfuse status`` checks the
same way, so it says stale where the next run reruns. The features readers refuse scores that are not probabilities, naming
the file and the row."""
from __future__ import annotations

import os
from collections import Counter

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import pipeline.infra.cache as cache
import stages.framework.runner as runner
from tests.support import stage_fakes


def tamper_keeping_size_and_mtime(path, offset=0, byte=b"X"):
    st = os.stat(path)
    data = bytearray(path.read_bytes())
    data[offset:offset + 1] = byte
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(path).st_size == st.st_size and os.stat(path).st_mtime_ns == st.st_mtime_ns


def test_an_upstream_output_edited_with_its_mtime_restored_is_recomputed(tmp_config, monkeypatch, capsys):
    calls = stage_fakes.install(monkeypatch, {"a": (), "b": ("a",)})
    cfg = tmp_config()
    runner.ensure(cfg, "b")
    out = cfg.stage_dir("a") / "out.txt"
    tamper_keeping_size_and_mtime(out)
    # status sees it as the run will: 'a' stale for its content, 'b' for its upstream ...
    st = runner.plan(cfg, "a")
    assert st["state"] == "stale" and st["why"] == f"output {out} content changed (sha256 differs)"
    assert runner.plan(cfg, "b")["state"] == "stale"
    # ... and the run agrees: 'a' is recomputed before 'b' could use the edited file.
    calls.clear()
    runner.ensure(cfg, "b")
    assert calls == ["a"] and out.read_text() == "a"
    assert "content changed (sha256 differs)" in capsys.readouterr().out


def test_status_through_the_cli_names_a_bit_flip_in_an_output(tmp_config, monkeypatch, capsys):
    from stages.commands import cli

    stage_fakes.install(monkeypatch, {"a": (), "b": ("a",)})
    cfg = tmp_config()
    runner.ensure(cfg, "b")
    capsys.readouterr()
    assert cli.status(cfg) == 0
    assert capsys.readouterr().out.split() == ["a", "up", "to", "date", "b", "up", "to", "date"]
    out = cfg.stage_dir("b") / "out.txt"
    tamper_keeping_size_and_mtime(out, byte=bytes([out.read_bytes()[0] ^ 1]))   # one bit
    assert cli.status(cfg) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["a", "up", "to", "date"]
    assert lines[1].startswith("b") and f"stale: output {out} content changed (sha256 differs)" in lines[1]


def test_each_file_is_hashed_once_per_run(tmp_config, monkeypatch):
    stage_fakes.install(monkeypatch, {"a": (), "b": ("a",), "c": ("a", "b")})
    cfg = tmp_config()
    runner.ensure(cfg, "c")
    seen: Counter = Counter()
    real = cache.sha256_file

    def counting(path, *a, **k):
        seen[os.path.abspath(path)] += 1
        return real(path, *a, **k)
    monkeypatch.setattr(cache, "sha256_file", counting)
    keys: dict = {}
    runner.ensure(cfg, "c", _keys=keys)
    runner.ensure(cfg, "b", _keys=keys)          # the CLI's second call (the 'after' stages) shares the memo
    assert set(seen) == {str(cfg.stage_dir(s) / "out.txt") for s in "abc"}
    assert max(seen.values()) == 1


def write_scores(path, scores, **extra_cols):
    scores = np.asarray(scores, np.float32)
    n, d = scores.shape
    cols = {k: pa.array(v) for k, v in extra_cols.items()}
    cols["scores"] = pa.FixedSizeListArray.from_arrays(pa.array(scores.ravel(), pa.float32()), d)
    pq.write_table(pa.table(cols), path)


GOOD = [[0.2, 0.3, 0.5], [0.1, 0.1, 0.8], [1.0, 0.0, 0.0], [0.25, 0.25, 0.5]]


@pytest.mark.parametrize("bad, words", [
    ([2.26e9, 0.3, 0.5], "a score outside [0, 1] (2.26e+09)"),
    ([np.nan, 0.3, 0.5], "non-finite scores"),
    ([0.2, -0.3, 1.1], "a score outside [0, 1] (-0.3)"),
    ([0.2, 0.2, 0.2], "scores summing to 0.6"),
])
def test_the_avd_features_reader_names_file_and_row_of_bad_scores(tmp_path, bad, words):
    from pipeline.scoring.features import read_features

    p = tmp_path / "avd.parquet"
    write_scores(p, GOOD, image=["a", "b", "c", "d"])
    assert read_features(p)[1].shape == (4, 3)
    rows = [list(r) for r in GOOD]
    rows[2] = bad
    write_scores(p, rows, image=["a", "b", "c", "d"])
    with pytest.raises(ValueError) as e:
        read_features(p)
    assert str(e.value).startswith(f"{p}: row 2 has ") and words in str(e.value)


def test_the_training_views_reader_names_file_and_row_of_bad_scores(tmp_path):
    from pipeline.banks.model_bank import FeaturesError, read_training_views

    p = tmp_path / "bigbird.parquet"
    n = len(GOOD)
    cols = dict(object=["o"] * n, camera=[1] * n, angle_deg=[0, 3, 6, 0], u_x=[1.0] * n, u_y=[0.0] * n,
                **{"pass": [-1, -1, -1, 0]})
    write_scores(p, GOOD, **cols)
    read_training_views(p, 1)
    rows = [list(r) for r in GOOD]
    rows[3] = [0.5, 0.5, 0.5]                    # an MC-dropout pass row
    write_scores(p, rows, **cols)
    with pytest.raises(FeaturesError, match=r"row 3 has scores summing to 1.5") as e:
        read_training_views(p, 1)
    assert e.value.path == str(p)


def test_scores_are_checked_in_blocks_and_the_first_bad_row_is_named(monkeypatch):
    from pipeline.scoring import features as F

    monkeypatch.setattr(F, "CHECK_ROWS", 3)           # blocks of 3 rows: the bad rows lie in later blocks
    rows = np.array(GOOD * 3, np.float32)
    F.check_scores(rows, "avd.parquet")
    rows[7] = [0.2, 0.2, 0.2]
    rows[10] = [np.nan, 0.5, 0.5]
    with pytest.raises(ValueError, match=r"^avd.parquet: row 7 has scores summing to 0.6.* \(2 bad row\(s\) in all\)"):
        F.check_scores(rows, "avd.parquet")
    with pytest.raises(ValueError, match=r"row 17 has scores summing to 0.6"):
        F.check_scores(rows, "avd.parquet", rows=np.arange(10, 22))
