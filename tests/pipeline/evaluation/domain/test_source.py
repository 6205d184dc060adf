"""The uncertainty source measured (pipeline/evaluation/domain/source.py): on a generated population of
crops where the dropout spread and |z| are planted correlated, ρ and the AUROC are high with CIs
above chance; planted independent, ρ ≈ 0 with a CI covering 0 and the AUROC's covering 0.5."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.domain import source as U


def residual_table(linked: bool, classes=12, crops=30, F=3, seed=0) -> pd.DataFrame:
    """Rows of ``domain.fit.crop_residuals`` (one per crop and component). Each crop has a latent
    spread; its residual is drawn with sd = that spread (linked) or with sd = another latent scale drawn
    the same way, independently (independent)."""
    rng = np.random.default_rng(seed)
    rows = []
    for c in range(classes):
        for i in range(crops):
            s, other = rng.uniform(0.2, 3.0, 2)
            for f in range(F):
                sd = s if linked else other
                rows.append({"scan": "s", "instance": f"c{c}", "image": f"im{c}_{i}", "component": f,
                             "obs": 0.5 + rng.normal(0, sd) * 0.1, "v_z": (0.01 * s) ** 2 * rng.uniform(0.8, 1.25),
                             "mu": 0.5, "var": 0.01, "x0": 1.0, "x1": 0.0})
    return pd.DataFrame(rows)


def test_per_crop_averages_the_components():
    t = residual_table(True, classes=2, crops=2, F=3)
    pc = U.per_crop(t)
    assert len(pc) == 4
    first = t[t["image"] == "im0_0"]
    assert pc.loc[0, "spread"] == pytest.approx(np.sqrt(first["v_z"]).mean())
    assert pc.loc[0, "abs_z"] == pytest.approx((np.abs(first["obs"] - 0.5) / 0.1).mean())


def test_spearman_and_auroc_against_scipy_and_by_hand():
    from scipy.stats import spearmanr
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=50), rng.normal(size=50)
    assert U.spearman(x, y) == pytest.approx(spearmanr(x, y)[0], abs=1e-12)
    assert U.auroc(np.array([1.0, 2.0, 3.0, 4.0]), np.array([0, 0, 1, 1])) == 1.0
    assert U.auroc(np.array([1.0, 1.0, 1.0]), np.array([0, 1, 1])) == 0.5      # ties count half
    assert np.isnan(U.auroc(np.ones(3), np.zeros(3)))


def test_planted_link_gives_high_rho_and_auroc():
    s = U.source_summary(U.per_crop(residual_table(True)), n_boot=400, seed=0)
    assert s["n_classes"] == 12 and s["n_crops"] == 360 and s["n_boot"] == 400
    assert s["rho"]["value"] > 0.5 and s["rho"]["ci_low"] > 0.3
    assert s["auroc"]["value"] > 0.8 and s["auroc"]["ci_low"] > 0.5
    assert s["rho"]["ci_low"] <= s["rho"]["value"] <= s["rho"]["ci_high"]
    assert "ranks crops far from their class model higher" in U.reading(s)


def test_independent_spread_gives_rho_near_zero_with_a_ci_covering_it():
    s = U.source_summary(U.per_crop(residual_table(False, seed=1)), n_boot=400, seed=0)
    assert abs(s["rho"]["value"]) < 0.15
    assert s["rho"]["ci_low"] < 0 < s["rho"]["ci_high"]
    assert s["auroc"]["ci_low"] < 0.5 < s["auroc"]["ci_high"]
    assert "no rank relation" in U.reading(s)


def test_too_few_crops_or_one_class_say_so():
    assert "note" in U.source_summary(U.per_crop(residual_table(True, classes=1, crops=2)), 100, 0)
    one = U.source_summary(U.per_crop(residual_table(True, classes=1, crops=20)), 100, 0)
    assert one["n_boot"] == 0 and np.isnan(one["rho"]["ci_low"])
    assert U.reading(one).startswith("too few")


def test_the_sources_say_whether_drop_connect_was_scored():
    from types import SimpleNamespace

    from pipeline.evaluation.domain.target_domain import mc_sources

    def cfg(arch, dc):
        eff = SimpleNamespace(dropout=0.2, drop_connect=dc)
        return SimpleNamespace(classifier=SimpleNamespace(arch=arch, dropout=0.5, efficientnet=eff))

    off = mc_sources(cfg("efficientnet_lite0", 0.0))
    assert off["source"] == "MC dropout (p = 0.2)" and off["drop_connect"].startswith("not scored")
    on = mc_sources(cfg("efficientnet_lite0", 0.2))
    assert "drop-connect (rate 0.2)" in on["source"] and "joint spread" in on["drop_connect"]
    assert mc_sources(cfg("alexnet", 0.2))["source"] == "MC dropout (p = 0.5)"   # AlexNet has no drop-connect


def test_the_evaluate_stage_writes_it_into_the_domain_fit():
    """TargetDomain on a generated scene: two classes, crops around each object, dropout passes
    whose spread grows with the crop's offset from the class model: summary()['uncertainty_source']."""
    from types import SimpleNamespace

    from pipeline.evaluation.domain.target_domain import TargetDomain
    from pipeline.method.gp import GPClassModels

    th = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], -1)
    Y = np.stack([0.5 + 0.1 * np.sin(th), 0.3 + 0.05 * np.cos(th)])
    ones = np.ones((2, 2))
    bank = GPClassModels(["a", "b"], [0, 1], [X, X], [Y, Y], 0.4 * ones, 0.01 * ones, 0.8 * ones, 1e-3 * ones)
    rng = np.random.default_rng(7)
    rows, scores = [], []
    for inst, obj in (("a", (0.0, 0.0)), ("b", (5.0, 0.0))):
        rows.append({"scan": "S", "instance": inst, "image": f"{inst}_det", "pass": -1, "difficulty": 1,
                     "cam_x": obj[0] + 1.0, "cam_y": obj[1]})
        scores.append(np.zeros(2))
        for i in range(40):
            ang = rng.uniform(-np.pi, np.pi)
            cam = (obj[0] + 2 * np.cos(ang), obj[1] + 2 * np.sin(ang))
            mu = np.array([0.5 + 0.1 * np.sin(ang), 0.3 + 0.05 * np.cos(ang)])
            s = rng.uniform(0.01, 0.3)
            centre = mu + rng.normal(0, s, 2)
            for p in range(8):
                rows.append({"scan": "S", "instance": inst, "image": f"{inst}{i}", "pass": p, "difficulty": 1,
                             "cam_x": cam[0], "cam_y": cam[1]})
                scores.append(centre + rng.normal(0, s, 2))
    avd = pd.DataFrame(rows)
    truth = {"instances": {"a": {"position": [0.0, 0.0], "yaw_deg": 0.0}, "b": {"position": [5.0, 0.0], "yaw_deg": 0.0}}}
    eff = SimpleNamespace(dropout=0.2, drop_connect=0.0)
    cfg = SimpleNamespace(evaluate=SimpleNamespace(max_difficulty=4, yaw_source="truth", variance_floor=1e-6,
                                                   bootstrap=200, seed=0, test_domain_variance="none"),
                          classifier=SimpleNamespace(arch="efficientnet_lite0", dropout=0.5, efficientnet=eff))
    dom = TargetDomain(cfg, avd, np.array(scores), bank, truth, {}, ["a", "b"], ["S"])
    src = dom.summary()["uncertainty_source"]
    assert src["n_crops"] == 80 and src["n_classes"] == 2 and src["n_boot"] == 200
    assert src["rho"]["value"] > 0.5                     # planted: spread and offset share the scale s
    assert src["source"] == "MC dropout (p = 0.2)" and src["drop_connect"].startswith("not scored")


def test_the_weighted_resample_equals_the_expanded_one():
    rng = np.random.default_rng(11)
    spread = np.round(rng.uniform(0, 2, 60), 1)              # ties on purpose
    abs_z = np.round(rng.uniform(0, 4, 60), 1)
    stat = U.WeightedStatistics(spread, abs_z)
    for _ in range(20):
        w = rng.integers(0, 4, 60).astype(float)
        idx = np.repeat(np.arange(60), w.astype(int))
        want = U.crop_statistics(spread[idx], abs_z[idx])
        np.testing.assert_allclose(stat(w), want, atol=1e-12)
    np.testing.assert_allclose(stat(np.ones(60)), U.crop_statistics(spread, abs_z), atol=1e-12)


def test_an_auroc_without_far_crops_in_some_resamples_says_why_it_has_no_ci():
    rng = np.random.default_rng(2)
    crops = pd.DataFrame({"instance": [f"c{i % 6}" for i in range(120)], "spread": rng.uniform(size=120),
                          "abs_z": np.r_[3.0, rng.uniform(0, 1, 119)]})      # one far crop, in class c0
    s = U.source_summary(crops, 200, 0)
    assert s["auroc"]["value"] is not None and np.isnan(s["auroc"]["ci_low"])
    assert s["auroc_note"].startswith("no CI:") and "resamples hold no crop" in s["auroc_note"]


def _two_level_crops(rng, k=10, n=40):
    """Classes that differ in both spread and |z| level (a badly fitting class has both high), with
    no relation between the two within any class."""
    lvl = np.linspace(0.5, 3.0, k)
    rows = []
    for c in range(k):
        rows.append(pd.DataFrame({"instance": f"c{c}", "spread": lvl[c] + rng.uniform(0, 0.3, n),
                                  "abs_z": lvl[c] * rng.uniform(0.5, 1.5, n)}))
    return pd.concat(rows, ignore_index=True)


def test_between_class_differences_raise_the_pooled_rho_but_not_the_within_class_one():
    est = U.source_summary(_two_level_crops(np.random.default_rng(0)), 400, 0)
    assert est["rho"]["ci_low"] > 0.5                                   # pooled: the classes' levels
    w = est["within"]
    assert w["rho"]["ci_low"] < 0 < w["rho"]["ci_high"]                 # within: nothing
    assert w["rho_spread"]["n_classes"] == 10 and w["rho_spread"]["min"] <= w["rho"]["value"] <= w["rho_spread"]["max"]
    assert "within each class" in U.reading(est)


def test_the_stratified_statistics_are_the_within_class_pairs():
    crops = _two_level_crops(np.random.default_rng(1), k=4, n=25)
    spread, z = crops["spread"].to_numpy(), crops["abs_z"].to_numpy()
    members = [np.flatnonzero(crops["instance"].to_numpy() == c) for c in sorted(set(crops["instance"]))]
    rho, auc = U.stratified(U.per_class(spread, z, members), np.ones(len(members)))
    # brute force: every (far, near) pair of crops of one class, ties half
    wins = total = 0.0
    for m in members:
        far, near = spread[m][z[m] > 2], spread[m][z[m] <= 2]
        wins += (far[:, None] > near[None, :]).sum() + 0.5 * (far[:, None] == near[None, :]).sum()
        total += len(far) * len(near)
    assert auc == pytest.approx(wins / total, abs=1e-12)
    per = [U.spearman(spread[m], z[m]) for m in members]
    assert rho == pytest.approx(np.average(per, weights=[len(m) for m in members]), abs=1e-12)
