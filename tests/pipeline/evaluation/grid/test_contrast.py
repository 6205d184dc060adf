"""The class-level contrast (pipeline/evaluation/grid/contrast.py; data.real_imagery.contrast): the
instance arm's cells pair with the default's (same tracks, seeds and draws), the engine's paired
difference instance - category detects a planted difference and not a null one, clustered as the
config says, and an unpaired cell is refused."""
from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.contrast import ARM, contrast_block
from pipeline.infra.config import EvaluateConfig
from pipeline.infra.config.evaluation import StatisticsConfig
from tests.pipeline.evaluation.grid.test_population import CX, FX, scene

WU, MB = "with_uncertainty", "model_based"


def test_the_instance_arm_runs_on_the_default_arms_tracks_seeds_and_draws():
    df, scores = scene(D=6)
    ev = dataclasses.replace(EvaluateConfig(), targets=("t",), tracks_per_target=4, track_length=4,
                             yaw_source="config", experiments=("biased", "randomized"))
    own = {"t": 0, "u": 1}
    indexes = {P.DEFAULT: {"candidate_sets": {"t": {"classes": ["t", "u"], "components": [0, 1]}}, "own_components": own},
               ARM: {"candidate_sets": {"t": {"classes": ["t", "u"], "components": [2, 4]}},
                     "own_components": {"t": 3, "u": 1}}}    # the instance arm's own peak components
    intr, steps = {"s1": (FX, CX), "s2": (FX, CX)}, {"s1": 0.3, "s2": 0.3}
    cells, tracks, _ = P.build_cells(ev, df, scores, indexes, None, intr, steps)
    by = {}
    for c in cells:
        by.setdefault((c.target, c.track), {})[c.variant] = c
    assert len(by) == len(tracks) == 4 and all(set(v) == {P.DEFAULT, ARM} for v in by.values())
    for pair in by.values():
        a, b = pair[P.DEFAULT], pair[ARM]
        assert (a.scan, a.data.images) == (b.scan, b.data.images)
        np.testing.assert_array_equal(a.data.cam_xy, b.data.cam_xy)
        assert a.classes == b.classes and a.truth == b.truth and a.seed == b.seed and a.settings == b.settings
        assert a.components == (0, 1) and b.components == (2, 4)       # each arm its own component choice
        # Simple Bayes reads each class's own peak component as its arm's index names it: score
        # column 0 (= the default's component 0) for t in the default arm, column 3 in the instance arm
        np.testing.assert_array_equal(a.data.own[:, :, 0], a.data.dropout[:, :, 0])
        assert not np.array_equal(a.data.own[:, :, 0], b.data.own[:, :, 0])
        np.testing.assert_array_equal(a.data.own[:, :, 1], b.data.own[:, :, 1])   # u: column 1 in both
        np.testing.assert_array_equal(a.data.own[:, :, 1], a.data.dropout[:, :, 1])
        for s in a.settings:                                             # the same localization draws
            assert P.cell_rng(a.seed, a.target, a.track, s).random() == P.cell_rng(b.seed, b.target, b.track, s).random()
        assert a.difficulty and not b.difficulty


def _table(shift: float, seed: int = 0) -> pd.DataFrame:
    """A generated cell table: 8 categories x 3 folds x 3 tracks x 2 settings in one scan (fewer than 8
    categories, or 2 scans, give no calibrated interval), two methods, both arms;
    the instance arm's With Uncertainty correct ratio is the category arm's + ``shift`` (clipped),
    Model Based the same in both arms up to small noise."""
    rng = np.random.default_rng(seed)
    rows = []
    for c in ("apple", "car", "cow", "cup", "dog", "horse", "pear", "tomato"):
        base_c = rng.uniform(0.3, 0.6)
        for f in (1, 2, 3):
            t = f"{c}__f{f}"
            for tr in range(3):
                for s in ("a", "b"):
                    for m in (WU, MB):
                        corr = float(np.clip(base_c + rng.normal(0, 0.1), 0, 1))
                        conf = float(np.clip(0.2 + rng.normal(0, 0.05), 0, 1))
                        common = {"target": t, "track": tr, "scan": "s0", "experiment": "randomized",
                                  "setting": s, "method": m}
                        rows.append({**common, "variant": P.DEFAULT, "correct_final": corr,
                                     "confident_error_final": conf, "log10_mgr95_final": rng.normal()})
                        d = shift if m == WU else rng.normal(0, 0.01)
                        rows.append({**common, "variant": ARM, "correct_final": float(np.clip(corr + d, 0, 1)),
                                     "confident_error_final": conf + rng.normal(0, 0.01),
                                     "log10_mgr95_final": rng.normal()})
    return pd.DataFrame(rows)


def _ev(cluster="category"):
    return dataclasses.replace(EvaluateConfig(), bootstrap=2000, statistics=StatisticsConfig(cluster=cluster))


def _row(block, method, metric):
    return next(r for r in block["rows"] if r["method"] == method and r["metric"] == metric)


def test_a_planted_difference_is_detected_and_a_null_one_is_not():
    block = contrast_block(_ev(), _table(shift=0.3))
    assert block["methods"] == [WU, MB] and block["cluster"] == "category"
    assert block["over"] == ["categories", "targets", "tracks"] and block["n"]["categories"] == 8
    wu = _row(block, WU, "correct_final")
    d = wu["difference"]
    assert d["outcome"] == "better" and d["outcome_holm"] == "better" and d["lo"] > 0.1
    # the difference is the engine's pooled difference of the two arms' values (means pool linearly)
    assert d["value"] == pytest.approx(wu["instance"]["value"] - wu["category"]["value"], abs=1e-9)
    mb = _row(block, MB, "correct_final")["difference"]
    assert mb["outcome_holm"] == "not distinguishable" and abs(mb["value"]) < 0.02
    # the Holm family: every method on each primary metric of the contrast, not the exploratory ones
    fam = [r for r in block["rows"] if "outcome_holm" in r["difference"]]
    assert {(r["method"], r["metric"]) for r in fam} == {(m, k) for m in (WU, MB)
                                                        for k in ("correct_final", "confident_error_final")}
    assert all(r["difference"]["family"] == 4 for r in fam)
    assert not _row(block, WU, "log10_mgr95_final")["primary"]
    null = contrast_block(_ev(), _table(shift=0.0))
    assert _row(null, WU, "correct_final")["difference"]["outcome_holm"] == "not distinguishable"


def test_the_clustering_is_the_configs_and_no_arm_means_no_block():
    t = _table(shift=0.3)
    by_target = contrast_block(_ev("target"), t)
    assert by_target["over"] == ["targets", "tracks"] and by_target["cluster"] == "target"
    assert contrast_block(_ev(), t[t["variant"] == P.DEFAULT]) is None


def test_an_unpaired_cell_is_refused():
    t = _table(shift=0.3)
    drop = t[(t["variant"] == ARM) & (t["method"] == WU)].index[:1]
    with pytest.raises(ValueError, match="not run on the same cells"):
        contrast_block(_ev(), t.drop(drop))


def test_the_models_stage_refuses_arms_with_other_candidates():
    from stages.models import contrast_check

    cat = {"a__f1": {"classes": ["a__f1", "b__f1"], "components": [0, 1]}}
    contrast_check(cat, {"a__f1": {"classes": ["a__f1", "b__f1"], "components": [5, 7]}})   # components may differ
    with pytest.raises(ValueError, match=r"candidate sets differ .* for 1 target\(s\) \(first: a__f1\)"):
        contrast_check(cat, {"a__f1": {"classes": ["a__f1", "c__f1"], "components": [0, 1]}})
    with pytest.raises(ValueError, match="first: b__f1"):
        contrast_check(cat, {**cat, "b__f1": {"classes": ["b__f1", "a__f1"], "components": [0, 1]}})
