"""The paper's §5.3 claims (pipeline.evaluation.simulation.claims), the confident-error definition shared with
the evaluate stage (pipeline.evaluation.metrics.spec), and the regime sweep (pipeline.evaluation.simulation.sweep).

Verdicts are checked on synthetic posteriors built so each statistic sits just on either side of
its threshold; the sweep on tiny fixed models; the default claims table of docs/results.md against
a run of the default configuration."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.metrics.labels import (
    MODEL_BASED,
    SIMPLE_BAYES,
    WITH_UNCERTAINTY,
)
from pipeline.evaluation.simulation import claims as CL
from pipeline.evaluation.simulation import scenarios as S
from pipeline.evaluation.simulation import sweep as SW
from pipeline.infra.config import SimulateConfig
from tests.pipeline.evaluation.simulation.test_simulation import fixed_models, small_sim

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

ROOT = Path(__file__).resolve().parents[4]
TRUTH = 1
P = CL.ClaimParams(step=2, confident_threshold=0.99, n_boot=500, seed=0)


def post_from_truth(pt: np.ndarray) -> np.ndarray:
    """Posteriors (R, K, 3) with P(truth = class index 1) = pt and the rest split evenly: correct
    exactly where pt > 1/3."""
    pt = np.asarray(pt, float)
    rest = (1 - pt) / 2
    return np.stack([rest, pt, rest], axis=-1)


def posts_with(**over) -> dict[str, np.ndarray]:
    """All three methods at P(truth) 0.9 everywhere (R = 100, K = 4), some replaced."""
    base = {m: post_from_truth(np.full((100, 4), 0.9)) for m in (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES)}
    base.update(over)
    return base


def claim(key: str, posts) -> dict:
    return CL.evaluate_claim(CL.BY_KEY[key], posts, TRUTH, P)


# -- verdicts flip at the thresholds ------------------------------------------------------------------
@pytest.mark.parametrize("n_low, holds", [(20, False), (21, True)])
def test_model_based_low_share_flips_above_twenty_percent(n_low, holds):
    pt = np.full((100, 4), 0.9)
    pt[:n_low, P.step] = 0.1                              # below 0.2 at the claim step only
    pt[n_low:n_low + 10, P.step - 1] = 0.1                # other steps do not count
    r = claim("mb_low_at_step", posts_with(**{MODEL_BASED: post_from_truth(pt)}))
    assert r["value"] == pytest.approx(n_low / 100) and r["holds"] is holds
    assert r["ci_low"] < r["value"] < r["ci_high"] and r["ci_side"] == "spans"


@pytest.mark.parametrize("q20, holds", [(0.329, False), (0.331, True)])
def test_ours_twentieth_percentile_flips_at_0_33(q20, holds):
    pt = np.full((101, 4), 0.9)
    pt[:, P.step] = np.linspace(q20 - 0.1, q20 + 0.4, 101)     # the 20th percentile is q20 itself
    r = claim("ours_p20_at_step", posts_with(**{WITH_UNCERTAINTY: post_from_truth(pt)}))
    assert r["value"] == pytest.approx(q20) and r["holds"] is holds
    assert r["ci_low"] <= r["value"] <= r["ci_high"]


@pytest.mark.parametrize("delta, holds", [(-1, False), (0, False), (1, True)])
def test_ours_more_correct_flips_at_zero_difference(delta, holds):
    mb = np.full((100, 4), 0.9)
    mb[:10, :] = 0.2                                      # Model Based wrong at 40 (realization, step)s
    ours = np.full((100, 4), 0.9)
    n = 40 - delta
    ours.reshape(-1)[:n] = 0.2                            # ours wrong at 40 - delta of them
    r = claim("ours_more_correct", posts_with(**{WITH_UNCERTAINTY: post_from_truth(ours),
                                                MODEL_BASED: post_from_truth(mb)}))
    assert r["value"] == pytest.approx(delta / 400) and r["holds"] is holds


@pytest.mark.parametrize("q20, holds", [(0.19, True), (0.21, False)])
def test_simple_bayes_poor_flips_at_0_2(q20, holds):
    pt = np.full((101, 4), 0.9)
    pt[:, P.step] = np.linspace(q20 - 0.1, q20 + 0.4, 101)
    r = claim("sb_poor_at_inverse", posts_with(**{SIMPLE_BAYES: post_from_truth(pt)}))
    assert r["value"] == pytest.approx(q20) and r["holds"] is holds


@pytest.mark.parametrize("n_bad, holds", [(5, True), (6, False)])
def test_graceful_flips_above_five_percent_confident_errors(n_bad, holds):
    ours = post_from_truth(np.full((100, 4), 0.6))
    ours[:n_bad, 1] = [0.995, 0.004, 0.001]               # confidently wrong at one step
    ours[50:60, 2] = [0.98, 0.01, 0.01]                   # wrong, but below 0.99: not confident
    r = claim("ours_graceful_bias", {WITH_UNCERTAINTY: ours})
    assert r["value"] == pytest.approx(n_bad / 100) and r["holds"] is holds


@pytest.mark.parametrize("n_wrong, holds", [(10, True), (11, False)])
def test_simple_bayes_well_flips_below_0_9(n_wrong, holds):
    pt = np.full((100, 4), 0.9)
    pt[:n_wrong, -1] = 0.2
    pt[:, 0] = 0.1                                        # only the final step counts
    r = claim("sb_well_bias", {SIMPLE_BAYES: post_from_truth(pt)})
    assert r["value"] == pytest.approx(1 - n_wrong / 100) and r["holds"] is holds


def test_verdict_and_ci_side():
    assert CL.holds(0.2001, ">", 0.2) and not CL.holds(0.2, ">", 0.2) and CL.holds(0.9, ">=", 0.9)
    assert not CL.holds(float("nan"), "<", 1.0)
    assert CL.ci_side(0.25, 0.4, ">", 0.2) == "holds"
    assert CL.ci_side(0.05, 0.15, ">", 0.2) == "fails"
    assert CL.ci_side(0.15, 0.25, ">", 0.2) == "spans"
    assert CL.ci_side(float("nan"), 0.25, ">", 0.2) == "spans"
    # the one outcome rule (records.outcome) on interval - threshold: an end on the threshold spans
    assert CL.ci_side(0.9, 0.95, ">=", 0.9) == "spans" and CL.ci_side(0.0, 0.05, "<=", 0.05) == "spans"
    assert CL.ci_side(0.01, 0.04, "<=", 0.05) == "holds" and CL.ci_side(0.06, 0.2, "<=", 0.05) == "fails"


def test_claims_need_the_step_on_the_track():
    with pytest.raises(ValueError, match="claim_step"):
        CL.evaluate_claims({"model_uncertainty": posts_with()}, TRUTH, dataclasses.replace(P, step=4))


def test_quantile_interval_covers_the_true_quantile():
    rng = np.random.default_rng(0)
    hits = [CL.quantile(rng.uniform(size=80), 0.2) for _ in range(400)]
    cover = np.mean([h.ci_low <= 0.2 <= h.ci_high for h in hits])
    assert 0.93 <= cover <= 0.995                          # >= 95 % by construction, not wildly more
    assert all(h.ci_low <= h.value <= h.ci_high for h in hits)


# -- the confident-error definition ----------------------------------------------------------------------
def test_confident_errors_hand_computed():
    p = np.array([[0.995, 0.004, 0.001],     # wrong, max 0.995: confident error
                  [0.004, 0.995, 0.001],     # right and confident: no
                  [0.98, 0.01, 0.01],        # wrong below the threshold: no
                  [0.99, 0.005, 0.005],      # exactly at the threshold: yes (>=)
                  [0.5, 0.5, 0.0]])          # a tie goes to the lowest index (as ``correct``): wrong, but 0.5
    with np.errstate(divide="ignore"):
        lp = np.log(p)
    np.testing.assert_array_equal(M.confident_errors(lp, 1, 0.99), [True, False, False, True, False])
    assert M.confident_error_rate(lp, 1, 0.99) == pytest.approx(2 / 5)
    assert M.confident_errors(lp, 1, 0.5)[-1]
    # Unnormalised log weights give the same answer; per-axis rates.
    np.testing.assert_array_equal(M.confident_errors(lp + 7.0, 1, 0.99), M.confident_errors(lp, 1, 0.99))
    two = np.stack([lp, lp[::-1]])                                        # (2, 5, 3)
    np.testing.assert_allclose(M.confident_error_rate(two, 1, 0.99, axis=0), [0.5, 0.5, 0, 0.5, 0.5])
    with pytest.raises(ValueError, match="threshold"):
        M.confident_errors(lp, 1, 0.0)
    # Extreme log posteriors (a truth probability of e^-2000) stay exact.
    assert M.confident_errors(np.array([0.0, -2000.0, -2000.0]), 1, 0.99)


def test_confident_errors_by_step_has_wilson_bands():
    p = post_from_truth(np.full((10, 3), 0.6))
    p[:3, 1] = [0.995, 0.004, 0.001]
    c = CL.confident_errors_by_step({WITH_UNCERTAINTY: p}, TRUTH, 0.99)[WITH_UNCERTAINTY]
    assert c["rate"] == [0.0, 0.3, 0.0] and c["overall"] == pytest.approx(0.1)
    assert c["ci_low"][1] < 0.3 < c["ci_high"][1] and c["ci_low"][0] == 0.0 < c["ci_high"][0]


# -- the sweep --------------------------------------------------------------------------------------------------
def tiny():
    sim = small_sim(realizations=4, claim_step=3, sweep_realizations=4)
    return sim, fixed_models(sim)


def test_sweep_is_deterministic_for_a_seed_and_reuses_the_default_draws():
    sim, models = tiny()
    g = SW.Grid("small", (1e-4, 5e-3), (0.1, 0.3), 4)
    p = CL.ClaimParams(step=3, confident_threshold=0.99, n_boot=200, seed=sim.seed)
    a = SW.run_sweep(models, sim, g, p)
    b = SW.run_sweep(models, sim, g, p)
    assert a == b and len(a) == 2 * 2 * len(CL.CLAIMS)
    c = SW.run_sweep(models, dataclasses.replace(sim, seed=7), g, p)
    assert [r["value"] for r in a] != [r["value"] for r in c]
    # The point (5e-3, 0.3) is the configured default with hand_made_noise = 5e-3: same claims.
    dsim = dataclasses.replace(sim, model_confidence="hand_made", hand_made_noise=5e-3, sigma_max=0.3)
    dm = S.configured_models(models, dsim)
    posts = {sc: S.run_scenario(dm, sc, dsim).posteriors for sc in S.SCENARIOS}
    direct = {r["key"]: r["value"] for r in CL.evaluate_claims(posts, sim.truth_class - 1, p)}
    at = {r["key"]: r["value"] for r in a if r["noise"] == 5e-3 and r["sigma_max"] == 0.3}
    assert at == pytest.approx(direct, abs=1e-12)
    # σ_max does not enter the localization-bias scenario: its claims are equal along σ_max.
    lb = [r for r in a if r["scenario"] == "localization_bias" and r["noise"] == 1e-4]
    assert lb[0]["value"] == lb[len(lb) // 2]["value"]
    # Confidence: a smaller noise variance gives a smaller predictive std, a larger ratio.
    sd = {r["noise"]: r["predictive_std"] for r in a}
    assert sd[1e-4] < sd[5e-3]


def test_grid_adds_the_default_point():
    sim = SimulateConfig()
    g = SW.grid(sim, "small", default=(0.005000000000000002, 0.25))
    assert 0.005 in g.noise and len(g.noise) == len(sim.sweep_noise)       # merged with the grid value
    assert 0.25 in g.sigma_max and len(g.sigma_max) == len(sim.sweep_sigma_max) + 1
    assert SW.grid(sim, "full").realizations == sim.sweep_full_realizations
    with pytest.raises(ValueError):
        SW.grid(sim, "off")


def synthetic_records(rule):
    out = []
    for v in (1e-4, 1e-3, 1e-2):
        for s in (0.1, 0.3, 0.5, 0.7):
            for spec in CL.CLAIMS:
                h = rule(spec.key, v, s)
                out.append({"noise": v, "sigma_max": s, "predictive_std": np.sqrt(v), "ratio": s / np.sqrt(v),
                            "key": spec.key, "scenario": spec.scenario, "statement": spec.statement,
                            "op": spec.op, "threshold": spec.threshold, "value": 1.0 if h else 0.0,
                            "holds": h, "ci_side": "holds" if h else "fails"})
    return out


def test_regime_sentence_is_computed_from_the_records():
    def rule(key, v, s):
        return {"mb_low_at_step": s >= 0.5, "ours_more_correct": False,
                "sb_well_bias": v <= 1e-3}.get(key, True)
    recs = synthetic_records(rule)
    r = SW.best_rule(recs, "mb_low_at_step")
    assert (r["field"], r["op"], r["threshold"], r["agree"]) == ("sigma_max", ">=", 0.5, 12)
    summ = SW.regime_summary(recs, (1e-3, 0.3))
    assert summ["never_hold"] == ["ours_more_correct"] and summ["mu_all_hold_at"] == []
    assert summ["best"]["holds"] and len(summ["best"]["holds"]) == 5 and summ["best"]["sigma_max"] == 0.5
    assert "hold together at none of the 12 grid points" in summ["sentence"]
    assert "mostly where σ_max ≥ 0.5" in summ["sentence"] and "At the default" in summ["sentence"]
    # Flip the one failing claim: now the model-uncertainty claims hold together somewhere.
    recs = synthetic_records(lambda k, v, s: rule(k, v, s) or k == "ours_more_correct")
    summ = SW.regime_summary(recs, (1e-3, 0.3))
    assert summ["mu_all_hold_at"] and "hold together at 6 of 12 grid points" in summ["sentence"]


# -- docs/results.md's claims table is what the default configuration gives ---------------------------------------
RESULTS = ROOT / "docs" / "results.md"


def results_table(marker: str, path: Path = RESULTS) -> dict[str, tuple[float, str]]:
    """{claim key: (statistic, verdict)} from the table between ``<!-- marker -->`` and its closing
    comment in ``path``."""
    text = path.read_text()
    start, end = f"<!-- {marker} -->", f"<!-- /{marker} -->"
    assert start in text and end in text, f"{path}: no {start} ... {end} block"
    block = text.split(start)[1].split(end)[0]
    rows = {}
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 4 and cells[0].startswith("`"):
            value = float(re.match(r"[-+]?\d*\.?\d+(?:e[-+]?\d+)?", cells[2].replace("−", "-")).group(0))
            rows[cells[0].strip("`")] = (value, cells[3])
    return rows


def test_default_claims_match_docs_results(tmp_path):
    from pipeline.infra.config import load_config

    sim = load_config(ROOT / "configs" / "synthetic.toml").simulate
    fitted, _ = S.fit_models(sim, progress=False)
    models = S.configured_models(fitted, sim)
    posts = {sc: S.run_scenario(models, sc, sim).posteriors for sc in sim.scenarios}
    p = CL.ClaimParams(step=sim.claim_step, confident_threshold=sim.confident_threshold, seed=sim.seed)
    got = {r["key"]: r for r in CL.evaluate_claims(posts, sim.truth_class - 1, p)}
    problems = table_problems(results_table("claims-default"), got)
    assert not problems, "docs/results.md claims table vs the default run:\n" + "\n".join(problems)
    # The comparison itself catches a table that disagrees: a changed value, a flipped verdict.
    text = RESULTS.read_text()
    for good, bad in (("0.0667 [0.0436, 0.101]", "0.0767 [0.0436, 0.101]"), ("| holds |\n", "| does not hold |\n")):
        assert good in text
        planted = tmp_path / "results.md"
        planted.write_text(text.replace(good, bad, 1))
        assert table_problems(results_table("claims-default", planted), got), bad


def table_problems(table: dict[str, tuple[float, str]], got: dict[str, dict]) -> list[str]:
    """Where the documented claims table disagrees with the computed claims (keys, values to 6e-4,
    verdicts, whether the CI spans the threshold)."""
    if set(table) != set(got):
        return [f"claims: documented {sorted(table)}, computed {sorted(got)}"]
    out = []
    for key, (value, verdict) in table.items():
        if not abs(got[key]["value"] - value) <= 6e-4:          # NaN disagrees too
            out.append(f"{key}: documented {value}, computed {got[key]['value']}")
        if verdict.startswith("holds") is not got[key]["holds"]:
            out.append(f"{key}: documented {verdict!r}, computed holds={got[key]['holds']}")
        if ("spans" in verdict) is not (got[key]["ci_side"] == "spans"):
            out.append(f"{key}: documented {verdict!r}, computed ci_side={got[key]['ci_side']}")
    return out


def test_page_findings_use_the_shared_confident_error_definition():
    from reports.simulate.findings import findings

    sim, models = tiny()
    sim = dataclasses.replace(sim, realizations=8, sigma_max=0.6)
    res = S.run_scenario(S.with_noise(models, 1e-5), "model_uncertainty", sim)
    import pandas as pd

    from pipeline.evaluation.metrics.results import frame

    df = frame([S.result_columns(res)], drop=("posterior",))
    ex = pd.DataFrame({"scenario": [], "step": [], "component": [], "class_mean": []})
    found = findings(df, ex, res.truth, {"model_uncertainty": res.posteriors}, 0.99)
    for m, p in res.posteriors.items():
        with np.errstate(divide="ignore"):
            rate = M.confident_error_rate(np.log(p), res.truth, 0.99)
        assert found["model_uncertainty"][m]["confident_wrong_overall"] == pytest.approx(rate)
    assert any(found["model_uncertainty"][m]["confident_wrong_overall"] > 0 for m in res.posteriors)


def test_config_checks_the_new_keys_at_load(tmp_config):
    from pipeline.infra.config import ConfigError

    cfg = tmp_config({"simulate": {"model_confidence": "hand_made", "sweep": "full"}})
    assert cfg.simulate.model_confidence == "hand_made" and cfg.simulate.sweep == "full"
    with pytest.raises(ConfigError, match=r"simulate\.claim_step.*track_steps"):
        tmp_config({"simulate": {"claim_step": 30}})
    with pytest.raises(ConfigError, match=r"simulate\.sweep"):
        tmp_config({"simulate": {"sweep": "huge"}})
    with pytest.raises(ConfigError, match=r"simulate\.sweep_noise"):
        tmp_config({"simulate": {"sweep_noise": []}})
