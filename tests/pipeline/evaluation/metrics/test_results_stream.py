"""ResultsWriter streams result blocks into one Parquet file equal to write_results' file."""
import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.metrics.results import ResultsWriter, result_block, write_results


def blocks(n=5, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        lp = np.log(rng.dirichlet(np.ones(3), (4 + i, 6)))
        posts = {"m1": lp, "m2": lp[::-1].copy()}
        out.append(result_block(posts, 1, variant="default", experiment="randomized", setting=f"s{i}",
                                sigma_m=0.1 * i, bias_x=0.0, bias_y=0.0, scan="A", target="t", track=i,
                                candidates="a,b,c", truth=1))
    return out


def test_streamed_file_equals_the_one_shot_file(tmp_path):
    bs = blocks()
    n = write_results(bs, tmp_path / "one.parquet", {"viewfuse.k": "v"})
    with ResultsWriter(tmp_path / "stream.parquet", {"viewfuse.k": "v"}, rows_per_group=50) as w:
        for b in bs:
            w.append(b)
    assert w.rows == n == sum(len(b["step"]) for b in bs)
    import pyarrow.parquet as pq
    assert pq.ParquetFile(tmp_path / "stream.parquet").num_row_groups > 1
    a, b = pd.read_parquet(tmp_path / "one.parquet"), pd.read_parquet(tmp_path / "stream.parquet")
    pd.testing.assert_frame_equal(a, b)
    assert pq.read_schema(tmp_path / "stream.parquet").metadata[b"viewfuse.k"] == b"v"


def test_failed_stream_leaves_no_file(tmp_path):
    with pytest.raises(RuntimeError):
        with ResultsWriter(tmp_path / "x.parquet", {}, rows_per_group=1) as w:
            w.write(blocks(1)[0])
            raise RuntimeError("boom")
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="no result blocks"):
        with ResultsWriter(tmp_path / "y.parquet", {}):
            pass
    assert not list(tmp_path.iterdir())


def test_metadata_given_at_the_end_makes_the_same_file(tmp_path):
    import pyarrow.parquet as pq

    bs = blocks()
    write_results(bs, tmp_path / "one.parquet", {"viewfuse.k": "v", "viewfuse.track": "3"})
    with ResultsWriter(tmp_path / "late.parquet", rows_per_group=30) as w:
        for b in bs:
            w.write(b)
        w.metadata = {"viewfuse.k": "v", "viewfuse.track": "3"}
    a, b = pq.read_table(tmp_path / "one.parquet"), pq.read_table(tmp_path / "late.parquet")
    assert a.equals(b) and a.schema.equals(b.schema, check_metadata=True)
    assert pq.ParquetFile(tmp_path / "late.parquet").num_row_groups > 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.parquet", "one.parquet"]   # spill removed
    with pytest.raises(ValueError, match="never set"):
        with ResultsWriter(tmp_path / "never.parquet") as w:
            w.write(bs[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.parquet", "one.parquet"]
