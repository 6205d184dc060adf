"""The simulation scenarios (paper §5.3): the Algorithm 2 measurement generator's statistics, the
scenario wiring (who gets which input, where the bias goes), determinism, and the stage end to end.

Fixtures are generated here and kept tiny (few steps, few realizations)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from pipeline.evaluation.simulation import claims as CL
from pipeline.evaluation.simulation import scenarios as S
from pipeline.infra.config import ConfigError, SimulateConfig
from pipeline.method.gp import GPClassModels
from tests.support.params import PARAMS

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


def small_sim(**kw) -> SimulateConfig:
    base = dict(realizations=6, track_steps=6, n_samples=5, n_loc_samples=4, restarts=0, chunk=4, claim_step=3)
    base.update(kw)
    return dataclasses.replace(SimulateConfig(), **base)


def fixed_models(sim: SimulateConfig, amp=0.01, ell=12.0, noise=0.005) -> GPClassModels:
    """The scenario's class models with fixed hyperparameters (no optimizer: fast, exact)."""
    X, Y = S.model_points(sim)
    C, F = Y.shape[:2]
    return GPClassModels(list(sim.class_names), list(range(F)), [X] * C, list(Y),
                         Y.mean(axis=2), np.full((C, F), amp), np.full((C, F), ell), np.full((C, F), noise))


def conditional(mu: np.ndarray, cov: np.ndarray, k: int, past: np.ndarray) -> tuple[float, float]:
    """GP conditional of step k given the values ``past`` at steps 0..k-1, one component, written
    out literally (explicit solve): mean ``mu_k + Σ_{k,p} Σ_p⁻¹ (past - mu_p)``, variance
    ``Σ_kk - Σ_{k,p} Σ_p⁻¹ Σ_{p,k}``: the reference the generator is checked against."""
    if k == 0:
        return float(mu[0]), float(cov[0, 0])
    w = np.linalg.solve(cov[:k, :k], cov[k, :k])
    return float(mu[k] + w @ (np.asarray(past, float) - mu[:k])), float(cov[k, k] - w @ cov[k, :k])


def toy_gp(K=5, seed=1):
    """A small joint Gaussian (one component) with strong correlation along the track."""
    t = np.linspace(0, 1, K)
    cov = 0.5 * np.exp(-(t[:, None] - t[None]) ** 2 / (2 * 0.4 ** 2)) + 0.05 * np.eye(K)
    mu = np.random.default_rng(seed).normal(size=K)
    return mu, cov


# -- the generator ------------------------------------------------------------------------------------
def test_nominal_draws_follow_the_gp_conditional_on_the_past():
    mu, cov = toy_gp()
    n = 40000
    x = S.draw_nominal(mu[None], cov[None], np.random.default_rng(0), n)[:, :, 0]   # (n, K)
    assert x.shape == (n, 5)
    for k in (1, 3, 4):
        past = x[:, :k]
        # Conditional mean is linear in the past: regress x_k on [1, x_past] and compare the
        # coefficients and residual variance to the literal GP conditional.
        A = np.column_stack([np.ones(n), past])
        coef, *_ = np.linalg.lstsq(A, x[:, k], rcond=None)
        resid = x[:, k] - A @ coef
        w = np.linalg.solve(cov[:k, :k], cov[k, :k])
        cond_var = cov[k, k] - w @ cov[k, :k]
        np.testing.assert_allclose(coef[1:], w, atol=0.05)
        assert abs(coef[0] - (mu[k] - w @ mu[:k])) < 0.05
        assert abs(resid.var() / cond_var - 1) < 0.05
        # The helper used as the reference agrees with the regression for one past draw.
        m_ref, v_ref = conditional(mu, cov, k, past[0])
        assert abs(m_ref - A[0] @ coef) < 0.06 and abs(v_ref - cond_var) < 1e-12


def test_nominal_draws_have_the_joint_mean_and_covariance():
    mu, cov = toy_gp(K=4)
    x = S.draw_nominal(np.stack([mu, mu + 1]), np.stack([cov, 2 * cov]), np.random.default_rng(3), 30000)
    for f, (m, c) in enumerate(((mu, cov), (mu + 1, 2 * cov))):
        np.testing.assert_allclose(x[:, :, f].mean(0), m, atol=0.03)
        np.testing.assert_allclose(np.cov(x[:, :, f].T), c, atol=0.04 * c.max())
    # Components are independent (paper Eq. 17).
    assert abs(np.corrcoef(x[:, 2, 0], x[:, 2, 1])[0, 1]) < 0.03


def test_noised_and_sample_residuals_have_variance_sigma_u2():
    rng = np.random.default_rng(5)
    nominal = rng.uniform(0, 1, size=(400, 10, 3))
    s2 = np.full((400, 10), 0.04)
    noised, samples = S.perturb(nominal, s2, 8, rng)
    assert noised.shape == nominal.shape and samples.shape == (400, 10, 8, 3)
    r1 = (noised - nominal).ravel()
    r2 = (samples - noised[..., None, :]).ravel()
    for r in (r1, r2):
        # chi-square 99.9% interval for the sample variance
        n = r.size
        lo, hi = stats.chi2.ppf([0.0005, 0.9995], n - 1) / (n - 1)
        assert lo * 0.04 < r.var(ddof=1) < hi * 0.04
        assert abs(r.mean()) < 4 * 0.2 / np.sqrt(n)
    # A step with sigma_u^2 = 0 leaves the measurement and its samples at the nominal value.
    n0, sm0 = S.perturb(nominal[:1, :1], np.zeros((1, 1)), 3, rng)
    np.testing.assert_array_equal(n0, nominal[:1, :1])
    np.testing.assert_array_equal(sm0[:, :, 0], nominal[:1, :1])


def test_uncertainty_levels_are_uniform_on_zero_to_sigma_max_squared():
    u = S.draw_sigma_u2(5000, 0.3, np.random.default_rng(11))
    assert u.min() >= 0 and u.max() <= 0.09
    assert stats.kstest(u, stats.uniform(0, 0.09).cdf).pvalue > 0.01
    # The test has power: sigma_u (not its square) uniform would be rejected.
    assert stats.kstest(np.sqrt(0.09 * u), stats.uniform(0, 0.09).cdf).pvalue < 1e-6


def test_to_simplex_clips_and_normalises():
    p = S.to_simplex(np.array([[0.5, -0.2, 0.3], [0.0, 0.0, 0.0]]), 1e-3)
    np.testing.assert_allclose(p.sum(-1), 1.0)
    assert p.min() > 0
    np.testing.assert_allclose(p[0], np.array([0.5, 1e-3, 0.3]) / 0.801)
    np.testing.assert_allclose(p[1], 1 / 3)


# -- scenario wiring ----------------------------------------------------------------------------------------
def test_track_and_model_points():
    sim = small_sim()
    xy = S.track_positions((-30, -20), 60, 7)
    np.testing.assert_allclose(xy[:, 1], -20)
    np.testing.assert_allclose(np.diff(xy[:, 0]), 10)      # eastward, evenly spaced
    X, Y = S.model_points(sim)
    A, Rr = len(sim.view_angles_deg), len(sim.view_radii)
    assert X.shape == (A * Rr, 2) and Y.shape == (3, 3, A * Rr)
    np.testing.assert_allclose(np.linalg.norm(X[:A], axis=1), sim.view_radii[0])
    # Class 2 (index 1) at 270-ish degrees (the inverse view) favours class 1's score.
    i = sim.view_angles_deg.index(260.0)
    assert np.argmax(Y[1, :, i]) == 0 and np.argmax(Y[1, :, 0]) == 1


def test_each_method_gets_its_input(monkeypatch):
    sim = small_sim()
    models = fixed_models(sim)
    seen = {}

    def spy(name, real):
        def f(*args, **kw):
            seen[name] = args
            return real(*args, **kw)
        return f

    # the simulation fuses through each registered method's own file
    from pipeline.method.methods import model_based as MB, simple_bayes as SB, with_uncertainty as WU

    monkeypatch.setattr(WU, "fuse_with_uncertainty", spy("wu", WU.fuse_with_uncertainty))
    monkeypatch.setattr(MB, "fuse_model_based", spy("mb", MB.fuse_model_based))
    monkeypatch.setattr(SB, "simple_bayes", spy("sb", SB.simple_bayes))
    true_xy = S.track_positions(sim.track_start, sim.track_length, sim.track_steps)
    mu, cov = models.predict(true_xy)

    d = S.draw_batch("model_uncertainty", sim, mu[1], cov[1], true_xy, range(3))
    S.fuse_batch(models, d, sim)
    _, wu_x, wu_z = seen["wu"]
    _, mb_x, mb_z = seen["mb"]
    (sb_s,) = seen["sb"]
    assert wu_x.shape == (3, 1, 6, 2) and np.array_equal(wu_x[:, 0], np.broadcast_to(true_xy, (3, 6, 2)))
    assert wu_z.shape == (3, 6, sim.n_samples, 3) and np.array_equal(wu_z, d.samples)
    assert np.array_equal(mb_x, np.broadcast_to(true_xy, (3, 6, 2))) and np.array_equal(mb_z, d.noised)
    assert not np.allclose(d.noised, d.nominal)            # MB/SB see the noised measurement
    np.testing.assert_allclose(sb_s, S.to_simplex(d.noised, sim.simple_bayes_floor))
    assert np.all((d.sigma_u2 >= 0) & (d.sigma_u2 <= sim.sigma_max ** 2))

    seen.clear()
    d = S.draw_batch("localization_bias", sim, mu[1], cov[1], true_xy, range(3))
    S.fuse_batch(models, d, sim)
    _, wu_x, wu_z = seen["wu"]
    _, mb_x, mb_z = seen["mb"]
    est = true_xy + np.array([sim.bias_east, 0.0])
    assert np.array_equal(mb_x, np.broadcast_to(est, (3, 6, 2)))      # MB trusts the biased estimate
    assert np.array_equal(mb_z, d.nominal) and np.all(d.sigma_u2 == 0)  # no model uncertainty
    assert wu_z.shape == (3, 6, 1, 3) and np.array_equal(wu_z[:, :, 0], d.nominal)
    assert wu_x.shape == (3, sim.n_loc_samples, 6, 2)
    # Pose samples are spread with the stated sigma around the biased estimates.
    big = dataclasses.replace(sim, n_loc_samples=2000)
    loc = S.draw_realization("localization_bias", big, mu[1], cov[1], true_xy, np.random.default_rng(0))["loc_samples"]
    np.testing.assert_allclose(loc.mean(0), est, atol=4 * sim.sigma_loc / np.sqrt(2000))
    assert abs((loc - est).std() / sim.sigma_loc - 1) < 0.05


def test_bias_moves_the_estimates_only():
    """The nominal measurements come from the true poses whatever the bias."""
    sim = small_sim()
    models = fixed_models(sim)
    true_xy = S.track_positions(sim.track_start, sim.track_length, sim.track_steps)
    mu, cov = models.predict(true_xy)
    a = S.draw_realization("localization_bias", sim, mu[1], cov[1], true_xy, np.random.default_rng(4))
    b = S.draw_realization("localization_bias", dataclasses.replace(sim, bias_east=30.0), mu[1], cov[1], true_xy,
                           np.random.default_rng(4))
    np.testing.assert_array_equal(a["nominal"], b["nominal"])
    np.testing.assert_allclose(b["estimates"] - a["estimates"], np.broadcast_to([38.0, 0.0], (6, 2)))


def test_scenarios_are_deterministic_and_posteriors_are_distributions():
    sim = small_sim()
    models = fixed_models(sim)
    for sc in S.SCENARIOS:
        r1 = S.run_scenario(models, sc, sim)
        r1b = S.run_scenario(models, sc, sim)
        r2 = S.run_scenario(models, sc, dataclasses.replace(sim, chunk=1))   # batch size: same draws
        r3 = S.run_scenario(models, sc, dataclasses.replace(sim, seed=1))
        for m in S.methods():
            p = r1.posteriors[m]
            assert p.shape == (sim.realizations, sim.track_steps, 3)
            np.testing.assert_allclose(p.sum(-1), 1.0, atol=1e-9)
            assert np.all(p >= 0)
            np.testing.assert_array_equal(p, r1b.posteriors[m])
            # Same draws per realization; only BLAS rounding differs with the batch shape.
            np.testing.assert_allclose(p, r2.posteriors[m], rtol=0, atol=1e-12)
            assert not np.allclose(p, r3.posteriors[m])
        cols = S.result_columns(r1)
        assert len(cols["step"]) == 3 * sim.realizations * sim.track_steps
        np.testing.assert_allclose(cols["p_truth"], cols["posterior"][:, sim.truth_class - 1])
        tab = S.summarize(pd.DataFrame({k: v for k, v in cols.items() if k != "posterior"}), PARAMS)
        assert set(tab["method"]) == set(S.methods()) and (tab["mgr95_overall"] >= tab["mgr75_overall"]).all()


def test_model_based_ignores_measurement_noise_that_ours_is_told_about():
    """With σ_u fixed large, Model Based gets confidently wrong more often than ours (the reason the
    paper's method carries the samples): a behavioural check on the wiring, not exact numbers."""
    sim = small_sim(realizations=40, track_steps=8, n_samples=10, sigma_max=0.3)
    models = fixed_models(sim, amp=0.005, noise=0.002)
    res = S.run_scenario(models, "model_uncertainty", sim)
    t = sim.truth_class - 1
    worst = {m: (1 - res.posteriors[m][..., t]).max(axis=1) for m in (S.WITH_UNCERTAINTY, S.MODEL_BASED)}
    assert np.mean(worst[S.MODEL_BASED] > 0.99) > np.mean(worst[S.WITH_UNCERTAINTY] > 0.99)


def test_validate_names_the_key():
    sim = dataclasses.replace(SimulateConfig(), scores_class2=SimulateConfig().scores_class2[:-3])
    with pytest.raises(ConfigError, match=r"simulate\.scores_class2"):
        S.validate(sim, "c.toml")
    bad = list(SimulateConfig().scores_class3)
    bad[0] = 0.9
    with pytest.raises(ConfigError, match=r"scores_class3.*sums to"):
        S.validate(dataclasses.replace(SimulateConfig(), scores_class3=tuple(bad)), "c.toml")
    with pytest.raises(ConfigError, match="example_realization"):
        S.validate(small_sim(example_realization=6), "c.toml")
    with pytest.raises(ConfigError, match=r"simulate\.claim_step.*track_steps"):
        S.validate(small_sim(claim_step=6), "c.toml")


def test_config_file_accepts_the_section(tmp_config):
    cfg = tmp_config({"simulate": {"realizations": 3, "bias_east": -4.0}})
    assert cfg.simulate.realizations == 3 and cfg.simulate.bias_east == -4.0
    with pytest.raises(ConfigError, match="simulate.sigma_max"):
        tmp_config({"simulate": {"sigma_max": -1.0}})
    with pytest.raises(ConfigError, match="simulate.scenarios"):
        tmp_config({"simulate": {"scenarios": ["nope"]}})


# -- the stage ------------------------------------------------------------------------------------------------
def test_stage_writes_results_example_and_report(tmp_config):
    import pyarrow.parquet as pq

    from stages.framework.runner import ensure

    cfg = tmp_config({"simulate": {"realizations": 4, "track_steps": 6, "n_samples": 4, "n_loc_samples": 4,
                                   "restarts": 0, "dpi": 40, "claim_step": 3, "sweep_noise": [1e-4],
                                   "sweep_sigma_max": [0.5], "sweep_realizations": 3}})
    ensure(cfg, "simulate")
    out = cfg.stage_dir("simulate")
    t = pq.read_table(out / "results.parquet")
    meta = {k.decode(): v.decode() for k, v in t.schema.metadata.items() if k.startswith(b"viewfuse.")}
    assert meta["viewfuse.config_hash"] == cfg.section_hash("simulate") and meta["viewfuse.seed"] == "0"
    df = t.to_pandas()
    assert set(df["scenario"]) == set(S.SCENARIOS) and set(df["method"]) == set(S.methods())
    assert len(df) == 2 * 3 * 4 * 6
    ex = pq.read_table(out / "example.parquet").to_pandas()
    assert len(ex) == 2 * 6 * 3
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["table"]) == 6 and "findings" in summary
    # The paper's claims, the confident errors per step and the sweep (2 x 2 grid: the default added).
    assert [c["key"] for c in summary["claims"]] == [c.key for c in CL.CLAIMS]
    assert all(isinstance(c["holds"], bool) and c["n"] == 4 for c in summary["claims"])
    assert len(summary["confident_errors"]["model_uncertainty"]["with_uncertainty"]["rate"]) == 6
    sw = summary["sweep"]
    assert sw["grid"]["sigma_max"] == [0.3, 0.5] and len(sw["records"]) == 2 * 2 * len(CL.CLAIMS)
    assert sw["summary"]["sentence"]
    html = (out / "index.html").read_text()
    assert html.index("The paper&#x27;s claims") < html.index("Overview")
    assert "Dirichlet (Tchuiev &amp; Indelman)&#x27; does not apply here" in html and sw["summary"]["sentence"].split(".")[0].replace("'", "&#x27;") in html
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == 1 + 1 + 2 * 5
    for p in pngs:
        assert f'src="{p}"' in html
    # The report's conventions: log10 MGR, the shared method names, every table value with its CI.
    assert "log10 MGR 95 %, all steps" in html and "With Uncertainty (Feldman &amp; Indelman)" in html
    assert "(ours)" not in html and "log MGR =" not in html
    import re
    # cell text without its no-wrap spans; the page writes a typographic minus
    cells = [re.sub(r"<[^>]+>", "", c).replace("−", "-") for c in re.findall(r'<td class="num">(.*?)</td>', html)]
    est = [c for c in cells if "[" in c]
    assert len(est) >= 2 * 3 * 4          # 2 scenarios x 3 methods x 4 metrics, each 'v [lo, hi]'
    for c in est:
        v, lo, hi = (float(x) for x in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", c)[:3])
        assert lo <= v <= hi and abs(v) < 1e6
    # A rerun with the same config is skipped (manifest up to date); a changed key reruns.
    from stages.framework.runner import digest
    manifest = json.loads((out / "manifest.json").read_text())
    assert ensure(cfg, "simulate") == digest(manifest)
    assert json.loads((out / "manifest.json").read_text()) == manifest
