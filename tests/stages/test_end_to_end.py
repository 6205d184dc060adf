"""The whole chain on a tiny configuration: data -> classifier -> features -> models -> evaluate ->
report, through the same runner the CLI uses. The upstream stages are the session's smoke run's
(configs/smoke.toml, tests/support/shared_upstream.py), copied; evaluate runs here with the tiny
world's population (two ablations, six realizations)."""
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.support.shared_upstream import copy_upstream, smoke_config, smoke_upstream
from tests.support.tiny_world import TINY

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


@pytest.fixture(scope="module")
def run_all(tmp_path_factory):
    from stages.framework.runner import ensure

    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path_factory.mktemp("e2e") / "artifacts")
    cfg = smoke_config(art, {"evaluate": TINY["evaluate"], "report": TINY["report"]})
    keys: dict = {}
    ensure(cfg, "evaluate", device="cpu", _keys=keys)
    ensure(cfg, "report", device="cpu", _keys=keys)
    return cfg


def test_every_stage_wrote_its_manifest(run_all):
    from stages.framework.runner import read_manifest
    for stage in ("data", "classifier", "features", "models", "evaluate", "report"):
        m = read_manifest(run_all, stage)
        assert m is not None and m["key"], stage


def test_results_cover_the_population(run_all):
    cfg = run_all
    ev = cfg.stage_dir("evaluate")
    t = pq.read_table(ev / "results.parquet")
    df = t.to_pandas()
    summary = json.loads((ev / "summary.json").read_text())
    pop = summary["population"]
    # Every target the scan shows, two distinct tracks each, four methods, every setting.
    assert pop["n_targets"] == len(cfg.data.synthetic.instances) and pop["skipped_targets"] == []
    assert pop["n_tracks"] == 2 * pop["n_targets"]
    assert set(df["experiment"]) == {"biased", "randomized", "sensitivity"}
    attribution = {"with_uncertainty_poses_only", "with_uncertainty_dropout_only"}
    assert set(df["method"]) == {"with_uncertainty", "model_based", "simple_bayes", "dirichlet",
                                 "view_independent"} | attribution
    assert set(df[df["variant"] != "default"]["method"]) == {"with_uncertainty", "model_based", "simple_bayes",
                                                             "dirichlet", "view_independent"}
    assert set(df["variant"]) == {"default", "models.noise_floor=dropout", "evaluate.test_domain_variance=cross_fit"}
    for target, cands in pop["candidates"].items():
        assert target in cands and len(cands) == 3
        rows = df[(df["target"] == target) & (df["experiment"] == "randomized") & (df["variant"] == "default")]
        assert set(rows["track"]) == {0, 1} and (rows["candidates"] == ",".join(cands)).all()
        assert (rows["truth"] == cands.index(target)).all()
        assert len(rows) == 2 * 2 * 6 * 4 * 7          # tracks x sigmas x realizations x steps x methods
        # the Dirichlet ignores poses: one posterior for every realization of a (track, setting)
        d = rows[rows["method"] == "dirichlet"]
        for _, g in d.groupby(["track", "setting", "step"]):
            assert np.ptp(np.stack(g["posterior"].to_numpy()), axis=0).max() == 0.0
    imgs = {}
    for tr in pop["tracks"]:
        assert len(tr["images"]) == 4 and len(set(tr["images"])) == 4
        imgs.setdefault(tr["target"], set()).add(frozenset(tr["images"]))
    assert all(len(v) == 2 for v in imgs.values())      # tracks of a target are distinct
    post = np.stack(df["posterior"].to_numpy())
    np.testing.assert_allclose(post.sum(1), 1.0, atol=1e-9)
    assert np.isfinite(df["log10_mgr"]).all() and (df["log10_mgr"] >= 0).all()
    # The contract of the population block.
    metrics = {"correct_final", "correct_overall", "prob_truth_final", "msde_final", "msde_overall", "log10_mgr75_final",
               "log10_mgr95_final", "log10_mgr75_overall", "log10_mgr95_overall", "nll_final", "nll_overall",
               "confident_error_final", "confident_error_overall", "wrong10_final",
               "ece_final", "ece_overall"}
    assert pop["methods"] == ["with_uncertainty", "model_based", "simple_bayes", "dirichlet", "view_independent"]
    for m in pop["methods"]:
        assert set(pop["pooled"][m]) == metrics
        for est in pop["pooled"][m].values():
            if est.get("withheld"):   # too few units for a calibrated interval: no interval at all
                assert est["ci_low"] is None and est["ci_high"] is None
            else:
                assert est["ci_low"] <= est["value"] <= est["ci_high"]
    assert set(pop["paired"]) == {"with_uncertainty-model_based", "with_uncertainty-simple_bayes",
                                  "with_uncertainty-dirichlet", "with_uncertainty-view_independent"}
    from pipeline.evaluation.metrics.spec import pool_of
    from pipeline.evaluation.statistics.records import consistent
    recs = pop["records"]
    assert "verdict" not in pop and "verdict_table" not in pop and "robust" not in pop   # records, no prose
    assert len(recs) == 4 * len(metrics) and all(consistent(r) for r in recs)
    assert {r["metric"] for r in recs if r["primary"]} == set(cfg.evaluate.primary_metrics)
    for r in recs:   # the number, its CI and its label are one statistic: the spec's pooling
        p = pop["paired"][r["comparison"]][r["metric"]]
        assert (p["value"], p["ci_low"], p["ci_high"]) == (r["value"], r["lo"], r["hi"])
        assert r["pooling"] == p["pooling"] == pool_of(r["metric"])
    assert pop["dirichlet"]["n_ss"] == cfg.evaluate.dirichlet.n_ss and pop["dirichlet"]["truth_std_final"]["n_cells"] > 0
    dj = json.loads((cfg.stage_dir("models") / "dirichlet" / "index.json").read_text())
    assert dj["classes"] == sorted(cfg.data.synthetic.instances) and dj["fits_not_converged"] == 0
    assert set(pop["paired"]["with_uncertainty-model_based"]) == metrics
    assert all({"loto_min", "loto_max", "loto_flips"} <= set(r) for r in recs)
    assert {m for m in metrics if pool_of(m) == "median"} == {m for m in metrics if m.startswith(("log10_mgr", "nll"))}
    assert set(pop["ablations"]) == {"models.noise_floor=dropout", "evaluate.test_domain_variance=cross_fit",
                                     "attribution"}
    att = pop["ablations"]["attribution"]
    assert set(att["paired"]) == {"with_uncertainty_poses_only-model_based", "with_uncertainty_dropout_only-model_based",
                                  "with_uncertainty-with_uncertainty_poses_only",
                                  "with_uncertainty-with_uncertainty_dropout_only"}
    # Test-domain fit and the cross-fitted variance (one scan: folds are the targets).
    dom = pop["domain_fit"]
    assert dom["n_crops"] > 0 and set(dom["test_domain_variance"]["per_fold"]) == set(pop["targets"])
    for kind in ("gp", "gp_plus_dropout", "gp_calibrated"):
        one = next(iter(next(iter(dom[kind]["per_class"].values())).values()))
        assert {"n", "share_gt2", "share_gt3", "coverage95", "pit"} <= set(one)
    assert dom["gp_plus_dropout"]["overall"]["coverage95"] >= dom["gp"]["overall"]["coverage95"]
    assert len(pop["difficulty"]["tracks"]) == pop["n_tracks"]
    # the declared primary comparison (evaluate.primary), its power, the paper's §5.5 test (no such setting here)
    prim = pop["primary"]
    assert (prim["method"], prim["baseline"], prim["metric"]) == (*cfg.evaluate.primary.methods, cfg.evaluate.primary.metric)
    assert consistent(prim["record"]) and prim["adjusted"] is False and "outcome_holm" not in prim["record"]
    assert {"object", "scan", "interaction", "track"} <= set(pop["power"]["components"])
    assert pop["paper_55"]["record"] is None and "biased_randomized" in pop["paper_55"]["missing"]
    assert set(pop["paper_55"]["mgr"]) == {"all"}
    track = json.loads((ev / "track.json").read_text())
    assert len(track["images"]) == 4 and len(set(track["images"])) == 4
    assert track["localization_error_m"] < 0.05
    for name in ("gp_models.npz", "bias_maps.npz"):
        assert (ev / name).is_file(), name
    json.loads((ev / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"))


def test_report_references_existing_figures(run_all):
    import re
    rep = run_all.stage_dir("report")
    html = (rep / "index.html").read_text()
    imgs = re.findall(r'<img[^>]+src="([^"]+)"', html)
    assert len(imgs) >= 5
    for src in imgs:
        assert (rep / src).is_file(), src
    assert 'class="summary' in html
    for anchor in ("calibration", "domain-fit", "attribution"):
        assert f'id="{anchor}"' in html, anchor
    for fig in ("reliability.png", "reliability_calibrated.png", "pit.png", "gp_ring.png"):
        assert f'src="{fig}"' in html, fig


def test_rerun_is_skipped_and_deterministic(run_all, capsys):
    from stages.framework.runner import ensure, read_manifest
    cfg = run_all
    before = read_manifest(cfg, "evaluate")
    res_before = (cfg.stage_dir("evaluate") / "results.parquet").read_bytes()
    ensure(cfg, "evaluate", device="cpu")
    assert read_manifest(cfg, "evaluate") == before
    assert "up to date" in capsys.readouterr().out
    # Forced rerun: same seed, same numbers.
    ensure(cfg, "evaluate", device="cpu", force=True)
    a = pq.read_table(cfg.stage_dir("evaluate") / "results.parquet").to_pandas()
    import io
    b = pq.read_table(io.BytesIO(res_before)).to_pandas()
    np.testing.assert_array_equal(np.stack(a["posterior"]), np.stack(b["posterior"]))


def test_compare_and_the_main_report_show_the_runs_own_pooled_values(run_all):
    """One statistic per number across pages: compare reads the run's pooled values and outcomes
    unchanged, and the main report prints each pooled value as the one formatter writes it."""
    from reports.compare.runs import compare
    from reports.shared.numbers import Estimate

    ev = run_all.stage_dir("evaluate")
    pop = json.loads((ev / "summary.json").read_text())["population"]
    c = compare([ev.parent])
    assert c.pooled
    for (m, k), vals in c.pooled.items():
        want, got = pop["pooled"][m][k], vals[0]
        assert [got[x] for x in ("value", "ci_low", "ci_high")] == [want[x] for x in ("value", "ci_low", "ci_high")]
    recs = {(r["comparison"], r["metric"]): r["outcome"] for r in pop["records"]}
    checked = [key for key in c.verdicts if key in recs]
    assert checked and all(c.verdicts[key][0]["outcome"] == recs[key] for key in checked)
    report = (run_all.stage_dir("report") / "index.html").read_text()
    for m in pop["pooled"]:
        assert Estimate.of(pop["pooled"][m]["correct_final"]).text() in report, m
