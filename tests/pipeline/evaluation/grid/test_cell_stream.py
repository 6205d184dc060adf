"""The evaluate stage's streamed cells (pipeline/evaluation/grid/cell_reduce.py): what it keeps of a
cell and writes of it equals what the stage computed from every cell's posteriors at once."""
import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.cell_reduce import reduce_cell
from pipeline.evaluation.metrics.results import (
    ResultsWriter,
    cell_metrics,
    result_block,
    write_results,
)
from pipeline.evaluation.statistics.pooled_calibration import cell_sums, track_sums
from pipeline.method.methods.dirichlet import DIRICHLET
from pipeline.method.names import WU_DROPOUT_ONLY, WU_POSES_ONLY
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models
from tests.pipeline.method.test_dirichlet_fusion import D
from tests.pipeline.method.test_dirichlet_fusion import models as dirichlet_models
from tests.support.params import PARAMS

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

SETTINGS = (P.Setting("biased", "b", 0.2, (0.1, 0.0), 1, 3), P.Setting("randomized", "r1", 0.1, (0.0, 0.0), 6, 3),
            P.Setting("randomized", "r2", 0.3, (0.0, 0.0), 6, 3))


def population():
    """Three tracks x two variants of small cells (the default with a Dirichlet and attribution)."""
    gp = ring_models()
    dm = dirichlet_models(C=3)
    dm.n_ss = 5
    cells = []
    for track in range(3):
        base = make_track(gp, truth=track % 3, K=4, seed=track)
        probs = np.random.default_rng(track).dirichlet(np.ones(D), size=(base.k, base.dropout.shape[1]))
        data = E.TrackData(base.images, base.cam_xy, base.obj_xy, base.yaw, base.dropout, probs=probs)
        for variant in ("default", "abl"):
            cells.append(P.Cell(variant, "t", track, "s1", tuple(gp.classes), tuple(gp.components), track % 3, data,
                                SETTINGS, seed=3, var_floor=1e-6, difficulty=variant == "default",
                                attribution=variant == "default", models={DIRICHLET: dm}))
    banks = {"default": gp, "abl": gp}
    return banks, cells, [P.run_cell(banks, c) for c in cells]


def old_blocks(cell, res):
    """The result blocks as the stage made them from the posteriors alone (before streaming)."""
    out = []
    by_label = {(s.experiment, s.label): s for s in cell.settings}
    for key, posts in res["posts"].items():
        s = by_label[key]
        out.append(result_block(posts, cell.truth, variant=cell.variant, experiment=s.experiment, setting=s.label,
                                sigma_m=float(s.sigma), bias_x=float(s.bias[0]), bias_y=float(s.bias[1]),
                                scan=cell.scan, target=cell.target, track=cell.track,
                                candidates=",".join(cell.classes), truth=cell.truth))
    return out


def test_streamed_results_file_and_kept_values_equal_the_all_at_once_ones(tmp_path):
    banks, cells, results = population()
    md = {"viewfuse.target": "t", "viewfuse.track": "1"}
    write_results([b for c, r in zip(cells, results) for b in old_blocks(c, r)], tmp_path / "old.parquet", md)
    kept = []
    with ResultsWriter(tmp_path / "new.parquet", rows_per_group=40) as w:   # metadata deferred, as the stage
        for cell, res in zip(cells, results):
            k, blocks = reduce_cell(cell, res, PARAMS, tables=cell.variant == "default")
            for b in blocks:
                w.write(b)
            kept.append(k)
        w.metadata = md
    old, new = pq.read_table(tmp_path / "old.parquet"), pq.read_table(tmp_path / "new.parquet")
    assert new.equals(old) and new.schema.equals(old.schema, check_metadata=True)
    assert pq.ParquetFile(tmp_path / "new.parquet").num_row_groups > 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.parquet", "old.parquet"]   # no spill file left

    # The cell table's rows, the calibration sums and the Dirichlet extras, as from the posteriors.
    rows = [r for k in kept for r in k["rows"]]
    want = [{"variant": c.variant, "target": c.target, "track": c.track, "scan": c.scan, "experiment": e,
             "setting": s, "method": m, **cell_metrics(lp, c.truth, PARAMS)}
            for c, r in zip(cells, results) for (e, s), posts in r["posts"].items() for m, lp in posts.items()]
    assert rows == want
    assert {WU_POSES_ONLY, WU_DROPOUT_ONLY, DIRICHLET} <= {r["method"] for r in rows}
    for variant in ("default", "abl"):
        a, b = track_sums(cells, kept, variant, PARAMS.ece_bins), track_sums(cells, results, variant, PARAMS.ece_bins)
        assert a.keys() == b.keys() and all(np.array_equal(a[key], b[key]) for key in a)
    for c, r, k in zip(cells, results, kept):
        assert k["difficulty"] == r["difficulty"]
        np.testing.assert_array_equal(k["extras"][DIRICHLET]["std"], r["extras"][DIRICHLET]["std"])
        np.testing.assert_array_equal(k["extras"][DIRICHLET]["posterior0"],
                                      np.exp(r["posts"][("biased", "b")][DIRICHLET][0]))
        assert ("tables" in k) == (c.variant == "default")


def test_the_showcase_tables_kept_from_the_grid_equal_a_recomputed_cell():
    # The stage keeps every default cell's single-track tables instead of its posteriors; the
    # chosen cell's tables equal experiments.summarize on that cell run again from its seeds.
    banks, cells, results = population()
    for cell, res in zip(cells, results):
        if cell.variant != "default":
            continue
        kept, _ = reduce_cell(cell, res, PARAMS, tables=True)
        again = P.run_cell(banks, cell)
        assert list(kept["tables"]) == list(again["posts"])
        for key, posts in again["posts"].items():
            assert kept["tables"][key] == E.summarize(posts, cell.truth, PARAMS)
        assert kept["calibration"].keys() == cell_sums(again["posts"], cell.truth, PARAMS.ece_bins).keys()


def test_showcase_and_population_agree_at_a_non_default_confident_threshold():
    # The showcase tables, the population's cell rows and the report's single-track bootstrap all
    # compute the confident-error rate from the one spec at the configured threshold.
    from pipeline.evaluation.metrics.results import frame
    from pipeline.evaluation.metrics.spec import Params, matrices
    from pipeline.evaluation.statistics.engine import over_realizations

    low = Params(0.6, 10)
    _, cells, results = population()
    moved = 0
    for cell, res in zip(cells, results):
        if cell.variant != "default":
            continue
        kept, blocks = reduce_cell(cell, res, low, tables=True)
        default, _ = reduce_cell(cell, res, PARAMS, tables=True)
        df = frame(blocks, drop=("posterior",))
        for row, other in zip(kept["rows"], default["rows"]):
            key, m = (row["experiment"], row["setting"]), row["method"]
            shown = kept["tables"][key][m]["confident_error_final"]
            assert row["confident_error_final"] == shown
            g = df[(df["setting"] == row["setting"]) & (df["method"] == m)]
            assert over_realizations(matrices(g), low, 50)["confident_error_final"]["value"] == pytest.approx(shown)
            moved += other["confident_error_final"] != shown
    assert moved > 0   # the threshold is used: some cells change between 0.6 and the default
