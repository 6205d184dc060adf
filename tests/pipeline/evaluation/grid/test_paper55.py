"""The paper's §5.5 test as it ran it (``grid/paper55.py``) and its event metric: the ten-times
event on log10 MGR, MGR percentiles over every track and realization, no verdict past a decade."""
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.evaluation.grid.paper55 import mgr_block, values_by_target
from pipeline.evaluation.metrics import spec as M


def test_the_ten_times_event_is_log10_mgr_of_at_least_one():
    # truth (class 0) at 1/11 vs a wrong class at 10/11: exactly ten times; 1/12 vs 9/12: nine times
    post = np.log(np.array([[1 / 11, 10 / 11], [3 / 12, 9 / 12], [0.9, 0.1], [1e-5, 1 - 1e-5]]))[:, None, :]
    v = M.step_values(post, 0, is_log=True)["log10_mgr"][:, 0]
    assert M.wrong_at_least(v, M.TEN_TIMES) == pytest.approx(0.5)          # the 10x and the 1e5x runs
    assert M.METRICS["wrong10_final"].higher_is_better is False


def _kept(rng, targets=12, tracks=4, R=20, shift=0.0, sd=0.3, independent=False):
    cells, kept = [], []
    for t in range(targets):
        for tr in range(tracks):
            cells.append(SimpleNamespace(variant="default", target=f"t{t}", track=tr))
            mb = np.abs(rng.normal(1.0, sd, R))
            po = np.abs(rng.normal(1.0, sd, R)) if independent else mb + shift
            kept.append({"final_mgr": {"br": {"model_based": mb, "with_uncertainty_poses_only": po},
                                       "other": {"model_based": mb + 100}}})
    return cells, kept


def test_percentiles_pool_every_track_and_realization_of_the_setting():
    cells, kept = _kept(np.random.default_rng(0), shift=-0.5)
    vals = values_by_target(cells, kept, ["br"])
    assert len(vals["model_based"]) == 12 and all(len(v) == 4 * 20 for v in vals["model_based"].values())
    b = mgr_block(vals, 400, 0, ["br"])
    every = np.concatenate(list(vals["model_based"].values()))
    assert b["methods"]["model_based"]["p95"]["value"] == pytest.approx(np.percentile(every, 95), abs=1e-12)
    assert b["n_values"]["model_based"] == 12 * 4 * 20
    pair = b["paired"]["with_uncertainty_poses_only-model_based"]
    assert pair["p95"]["value"] == pytest.approx(-0.5, abs=1e-9) and pair["verdict"] == "better"   # lower MGR


def test_an_interval_spanning_decades_gives_no_verdict():
    cells, kept = _kept(np.random.default_rng(1), targets=8, tracks=1, R=3, sd=20.0, independent=True)
    b = mgr_block(values_by_target(cells, kept, ["br"]), 400, 0, ["br"])
    pair = b["paired"]["with_uncertainty_poses_only-model_based"]
    assert pair["decades"] > 1 and pair["verdict"] is None and "decades" in pair["no_verdict"]


def test_too_few_units_of_a_level_withhold_the_interval_as_every_mean_does():
    cells, kept = _kept(np.random.default_rng(2), targets=6, shift=-0.5)
    b = mgr_block(values_by_target(cells, kept, ["br"]), 200, 0, ["br"])
    pair = b["paired"]["with_uncertainty_poses_only-model_based"]
    assert "6 targets" in b["withheld"] and pair["verdict"] is None and "6 targets" in pair["no_verdict"]
    assert np.isnan(b["methods"]["model_based"]["p95"]["ci_low"])
    # scans the cells name are a level: 10 objects crossed with 3 scans withhold; with 8 scans they vary
    for n_scans, held in ((3, True), (8, False)):
        cells, kept = _kept(np.random.default_rng(3), targets=10, tracks=n_scans, shift=-0.5)
        for c in cells:
            c.scan = f"S{c.track}"
        b = mgr_block(values_by_target(cells, kept, ["br"]), 200, 0, ["br"], cluster="crossed")
        assert b["levels"] == {"targets": 10, "scans": n_scans} and ("withheld" in b) == held
        assert "scans" in b["over"]


def test_the_weighted_percentile_is_the_percentile_of_the_repeated_values():
    from pipeline.evaluation.grid.paper55 import QUANTILES, _weighted_quantiles

    rng = np.random.default_rng(4)
    x = np.sort(np.concatenate([rng.normal(size=40), [np.inf, -np.inf]]))
    block = rng.integers(0, 6, size=len(x))
    w = rng.integers(0, 3, size=(25, 6))
    got = _weighted_quantiles(x, block, w)
    for i in range(len(w)):
        rep = np.repeat(x, w[i][block])
        want = M.percentile(rep, list(QUANTILES)) if len(rep) else np.full(len(QUANTILES), np.nan)
        assert got[i] == pytest.approx(want, rel=1e-12, nan_ok=True)
