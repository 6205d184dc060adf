"""Pooled ECE: the population's posteriors weighted as every pooled value, with paired CIs."""
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.evaluation.metrics import calibration as K
from pipeline.evaluation.statistics.pooled_calibration import (
    hierarchy_of,
    pooled_ece,
    track_sums,
)
from tests.support.params import PARAMS


def _population(rng, n_targets=4, tracks=(2, 3, 2, 4), R=5, Kn=3, C=3):
    cells, results, allp = [], [], {"a": [], "b": []}
    for t in range(n_targets):
        for j in range(tracks[t]):
            posts = {}
            for s in ("s1", "s2"):
                lp = {m: np.log(rng.dirichlet(np.ones(C) * (0.3 if m == "a" else 3.0), size=(R, Kn))) for m in "ab"}
                posts[("randomized", s)] = lp
                for m in "ab":
                    allp[m].append((t, lp[m]))
            cells.append(SimpleNamespace(variant="default", target=f"t{t}", track=j, truth=t % C))
            results.append({"posts": posts})
    return cells, results


def test_equal_sizes_reduce_to_the_plain_ece_and_weights_follow_the_population():
    rng = np.random.default_rng(0)
    cells, results = _population(rng, tracks=(2, 2, 2, 2))
    sums = track_sums(cells, results, "default", PARAMS.ece_bins)
    assert all(np.allclose(v[:, 0].sum(axis=-1), 1.0) for v in sums.values())   # each track weighs 1
    out = pooled_ece(hierarchy_of(sums, 300, 0), sums, ["a", "b"], [("a", "b")])
    conf, ok = [], []
    for c, r in zip(cells, results):
        for lp in r["posts"].values():
            cf, o = K.top_label(lp["a"], c.truth)
            conf.append(cf[:, -1]), ok.append(o[:, -1])
    want = K.ece(np.concatenate(conf), np.concatenate(ok))
    est = out["pooled"]["a"]["ece_final"]
    assert est["value"] == pytest.approx(want)
    assert est["ci_low"] <= est["value"] <= est["ci_high"]
    d = out["paired"]["a-b"]["ece_final"]
    assert d["value"] == pytest.approx(est["value"] - out["pooled"]["b"]["ece_final"]["value"])
    assert d["unit"] == "targets" and 0 <= d["wins"] <= 1 and "loto_min" in d
    assert set(out["reliability"]["a"]) == {"final", "overall"}


def test_a_target_with_more_tracks_does_not_weigh_more():
    rng = np.random.default_rng(1)
    cells, results = _population(rng, tracks=(1, 1, 1, 6))
    sums = track_sums(cells, results, "default", PARAMS.ece_bins)
    # duplicate target t3's tracks: its weight stays 1/4, so the pooled ECE is unchanged
    extra = {(m, t, j + 10): v for (m, t, j), v in sums.items() if t == "t3"}
    a = pooled_ece(hierarchy_of(sums, 100, 0), sums, ["a"], [])["pooled"]["a"]["ece_final"]["value"]
    b = pooled_ece(hierarchy_of({**sums, **extra}, 100, 0), {**sums, **extra}, ["a"], [])["pooled"]["a"]["ece_final"]["value"]
    assert a == pytest.approx(b)
