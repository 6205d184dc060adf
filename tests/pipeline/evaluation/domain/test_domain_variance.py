"""Test-domain fit (standardized residuals) and the cross-fitted test-domain variance."""
import numpy as np
import pandas as pd
import pytest
from scipy import stats

from pipeline.evaluation.domain import fit as D
from pipeline.evaluation.domain import variance as V
from pipeline.method.gp import GPClassModels


def _models():
    th = np.linspace(-np.pi, np.pi, 40, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], -1)
    Y = np.stack([0.5 + 0.2 * np.sin(th), 0.3 + 0.1 * np.cos(2 * th)])
    return GPClassModels(["a"], [0, 1], [X], [Y], [[0.5, 0.3]], [[0.04, 0.01]], [[0.8, 0.5]], [[1e-3, 2e-3]])


def test_residuals_of_draws_from_the_gps_own_predictive_are_standard_normal():
    m = _models()
    rng = np.random.default_rng(0)
    th = rng.uniform(-np.pi, np.pi, 4000)
    x = np.stack([np.cos(th), np.sin(th)], -1)
    mu, var = m.marginal(x)
    obs = mu[:, 0] + np.sqrt(var[:, 0]) * rng.standard_normal(mu[:, 0].shape)
    tab = pd.DataFrame({"obs": obs.ravel(), "mu": mu[:, 0].ravel(), "var": var[:, 0].ravel(),
                        "v_z": 0.0, "instance": "a", "component": np.tile([0, 1], len(x)), "scan": "s"})
    z = D.standardized(tab, "gp")
    s = D.fit_summary(z)
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1) < 0.05
    assert s["share_gt2"] == pytest.approx(0.0455, abs=0.01) and s["coverage95"] == pytest.approx(0.95, abs=0.01)
    assert stats.kstest(z, "norm").pvalue > 0.01
    assert max(abs(h - 0.1) for h in s["pit"]) < 0.02
    # residuals twice as wide as the model says: far outside
    wide = D.fit_summary(2 * z)
    assert wide["share_gt3"] > 0.1 and wide["coverage95"] < 0.7


def test_test_variance_adds_to_the_test_noise_only():
    m = _models()
    x = np.array([[1.0, 0.0], [0.0, 1.0]])
    mu0, var0 = m.marginal(x)
    cal = m.with_test_variance([0.1, 0.2])
    mu1, var1 = cal.marginal(x)
    assert np.allclose(mu0, mu1) and np.allclose(var1 - var0, [[0.1, 0.2]])
    mu2, cov2 = cal.predict(x[None])
    _, cov0 = m.predict(x[None])
    assert np.allclose(cov2 - cov0, np.einsum("cf,kl->cfkl", [[0.1, 0.2]], np.eye(2))[None])
    sub = cal.subset(["a"], [1])
    assert sub.test_noise.tolist() == [[2e-3 + 0.2]]


def test_ml_variance_recovers_the_added_variance():
    rng = np.random.default_rng(2)
    v = rng.uniform(0.001, 0.01, 20000)
    r = rng.standard_normal(20000) * np.sqrt(v + 0.05)
    assert V.ml_variance(r, v) == pytest.approx(0.05, rel=0.05)
    r0 = rng.standard_normal(20000) * np.sqrt(v) * 0.8          # narrower than the model: no variance
    assert V.ml_variance(r0, v) == 0.0


def _table(rng, n=400):
    rows = []
    for scan in ("A", "B"):
        for inst in ("p", "q", "r"):
            for comp in (3, 7):
                v = rng.uniform(0.001, 0.01, n)
                rows.append(pd.DataFrame({"scan": scan, "instance": inst, "image": np.arange(n).astype(str),
                                          "component": comp, "mu": 0.0, "var": v, "v_z": 0.0,
                                          "obs": rng.standard_normal(n) * np.sqrt(v + 0.02 * (1 + (comp == 7)))}))
    return pd.concat(rows, ignore_index=True)


def test_cross_fit_never_reads_the_evaluated_scans_labels():
    tab = _table(np.random.default_rng(3))
    col, est, used = V.cross_fit(tab, [3, 7])
    assert col == "scan" and set(est) == {"A", "B"}
    assert est["A"][7] == pytest.approx(0.04, rel=0.15) and used["A"][3] == 3 * 400
    planted = tab.copy()
    planted.loc[planted["scan"] == "A", "obs"] += 1e3            # a huge error in scan A's labelled crops
    _, est2, _ = V.cross_fit(planted, [3, 7])
    assert est2["A"] == est["A"]                                   # scan A's cells: unchanged
    assert est2["B"][3] > 1e4                                      # scan B's cells did read it
    assert V.cell_fold(col, "A", "p") == "A"


def test_single_scan_cross_fit_never_reads_the_targets_own_crops():
    tab = _table(np.random.default_rng(4))
    one = tab[tab["scan"] == "A"].reset_index(drop=True)
    col, est, _ = V.cross_fit(one, [3, 7])
    assert col == "instance" and set(est) == {"p", "q", "r"}
    planted = one.copy()
    planted.loc[planted["instance"] == "q", "obs"] *= 1e4
    _, est2, _ = V.cross_fit(planted, [3, 7])
    assert est2["q"] == est["q"] and est2["p"] != est["p"]
    assert V.cell_fold(col, "A", "q") == "q"
    d = V.row_variances(one, col, est)
    assert d[(one["instance"] == "p") & (one["component"] == 7)].tolist()[0] == est["p"][7]


def test_crop_residuals_average_the_dropout_passes_at_the_true_direction():
    m = _models()
    rows, scores = [], []
    rng = np.random.default_rng(5)
    for img, cam in (("i1", (2.0, 0.0)), ("i2", (0.0, 3.0))):
        for p in (-1, 0, 1, 2):
            rows.append({"scan": "S", "instance": "a", "image": img, "pass": p, "difficulty": 1,
                         "cam_x": cam[0], "cam_y": cam[1]})
            scores.append(rng.uniform(0, 1, 4))
    avd = pd.DataFrame(rows)
    scores = np.array(scores)
    tab = D.crop_residuals(avd, scores, m, {("S", "a"): (np.zeros(2), 0.0)}, max_difficulty=4, var_floor=1e-6)
    assert len(tab) == 2 * 2                                      # crops x components
    r = tab[(tab["image"] == "i2") & (tab["component"] == 1)].iloc[0]
    passes = scores[[5, 6, 7], 1]                                 # dropout passes of i2, score index 1
    assert r["obs"] == pytest.approx(passes.mean()) and r["v_z"] == pytest.approx(passes.var())
    mu, var = m.marginal(np.array([[0.0, 1.0]]))                  # camera straight "north" of the object
    assert r["mu"] == pytest.approx(mu[0, 0, 1]) and r["var"] == pytest.approx(var[0, 0, 1])
    assert (r["x0"], r["x1"]) == pytest.approx((0.0, 1.0))
    none = D.crop_residuals(avd, scores, m, {}, max_difficulty=4, var_floor=1e-6)
    assert none.empty


def test_the_fusion_engine_carries_the_test_domain_variance():
    from pipeline.method import engine

    m = _models()
    cal = m.with_test_variance([0.1, 0.2])
    th = np.random.default_rng(6).uniform(-np.pi, np.pi, (3, 4))
    X = np.stack([np.cos(th), np.sin(th)], -1)                    # (B, K, 2) on the unit circle
    mu_e, cov_e = engine.predictive(cal, X)
    mu_g, cov_g = cal.predict(X)
    assert np.allclose(mu_e, mu_g, atol=1e-9) and np.allclose(cov_e, cov_g, atol=1e-9)
    _, cov0 = engine.predictive(m, X)
    assert np.allclose(cov_e - cov0, np.einsum("cf,kl->cfkl", [[0.1, 0.2]], np.eye(4))[None], atol=1e-9)


def test_summaries_per_class_and_component_are_those_of_their_own_rows():
    rng = np.random.default_rng(11)
    n = 400
    table = pd.DataFrame({"instance": rng.choice(["b", "a", "c"], n), "component": rng.choice([7, 2, 30], n)})
    table = table[~((table["instance"] == "c") & (table["component"] == 30))]   # a class without one component
    z = {"gp": rng.normal(size=len(table)), "gp_calibrated": rng.standard_t(3, size=len(table))}
    out = D.summarize(table, z)
    inst, comp = table["instance"].to_numpy(), table["component"].to_numpy()
    for kind, zk in z.items():
        assert out[kind]["overall"] == D.fit_summary(zk)
        per = out[kind]["per_class"]
        assert list(per) == ["a", "b", "c"] and list(per["a"]) == ["2", "7", "30"] and list(per["c"]) == ["2", "7"]
        for c, by in per.items():
            for f, s in by.items():
                assert s == D.fit_summary(zk[(inst == c) & (comp == int(f))])   # the rows in table order


def test_crop_residual_rows_run_component_major_within_each_scan_and_instance():
    m = _models()
    rows, scores = [], []
    rng = np.random.default_rng(2)
    for scan, inst, img, cam in (("S", "a", "i1", (2.0, 0.0)), ("S", "a", "i2", (0.0, 3.0)), ("R", "a", "j", (1.0, 3.0))):
        for p in (-1, 0, 1):
            rows.append({"scan": scan, "instance": inst, "image": img, "pass": p, "difficulty": 1,
                         "cam_x": cam[0], "cam_y": cam[1]})
            scores.append(rng.uniform(0, 1, 4))
    poses = {("S", "a"): (np.zeros(2), 0.0), ("R", "a"): (np.ones(2), 0.5)}
    tab = D.crop_residuals(pd.DataFrame(rows), np.array(scores, np.float32), m, poses, max_difficulty=4, var_floor=1e-6)
    assert list(zip(tab["scan"], tab["image"], tab["component"])) == [
        ("R", "j", 0), ("R", "j", 1), ("S", "i1", 0), ("S", "i2", 0), ("S", "i1", 1), ("S", "i2", 1)]
    assert tab["component"].dtype == np.int64 and tab["obs"].dtype == np.float64
    assert tab["obs"].iloc[3] == np.float64(np.array(scores, np.float32)[[4, 5], 0].astype(float).mean())
