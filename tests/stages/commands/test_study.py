"""The seed study: per-seed configs, side-by-side summary, verdict agreement, reuse of finished seeds."""
from __future__ import annotations

import json

import pytest

from pipeline.infra.cache import write_json
from reports.study.page import render_html
from stages.commands.study import outcomes, run_study, seed_config, summarize


def _record(outcome: str, value: float, metric: str = "correct_final") -> dict:
    return {"comparison": "with_uncertainty-model_based", "method": "with_uncertainty", "baseline": "model_based",
            "metric": metric, "pooling": "mean", "value": value, "lo": value - 0.1, "hi": value + 0.1,
            "over": ["targets", "tracks"], "n": {"targets": 12, "tracks": 96}, "better": "higher",
            "outcome": outcome, "primary": True}


def _population(outcome: str, value: float) -> dict:
    cell = {"value": value, "ci_low": value - 0.1, "ci_high": value + 0.1}
    return {"pooled": {"with_uncertainty": {"correct_final": cell}, "model_based": {"correct_final": cell}},
            "records": [_record(outcome, value)]}


def _fake_ensure(outcome_by_seed: dict, calls: list):
    """Stands in for the runner: 'runs' a seed's chain only when its evaluate manifest is absent,
    writing a tiny card and evaluate/summary.json, as the real manifests make finished seeds skip."""
    def ensure(cfg, name, force=False, device="auto", threads=0, _keys=None):
        calls.append((cfg.run.name, name, cfg.classifier.seed))
        if name == "data":
            write_json(cfg.stage_dir("data") / "manifest.json", {"stage": "data"})
            return "k"
        ev = cfg.stage_dir("evaluate")
        if (ev / "manifest.json").is_file() and not force:
            return "k"
        seed = cfg.classifier.seed
        write_json(cfg.stage_dir("classifier") / "card.json", {"accuracy": 0.9 + seed / 100,
                                                               "accuracy_ci95": [0.88 + seed / 100, 0.92 + seed / 100]})
        diags = [{"train_std": 0.05, "at_bound": []}, {"train_std": 0.002, "at_bound": ["noise at lower bound"]},
                 {"train_std": 0.03, "at_bound": ["length_scale at lower bound"] * seed}]
        write_json(cfg.stage_dir("models") / "index.json", {"diagnostics": diags, "varying_std_threshold": 0.01,
                                                            "varying_fits_at_bound": seed})
        write_json(ev / "summary.json", {"population": _population(*outcome_by_seed[seed])})
        write_json(ev / "manifest.json", {"finished": f"run {len(calls)}", "seconds": 1.5 + seed})
        return "k"
    return ensure


def test_seed_config_moves_the_run_folder_and_changes_only_the_classifier_seed(tmp_config):
    cfg = tmp_config({"study": {"seeds": [3, 5]}})
    s = seed_config(cfg, 5)
    assert s.run_dir == cfg.run_dir / "study" / "seed-5"
    assert s.classifier.seed == 5 and cfg.classifier.seed == 0
    assert (s.data, s.features, s.models, s.evaluate) == (cfg.data, cfg.features, cfg.models, cfg.evaluate)
    assert s.section_hash("data") == cfg.section_hash("data")  # shared data has the same cache key
    assert s.section_hash("classifier") != cfg.section_hash("classifier")


def test_summary_puts_seeds_side_by_side_and_says_whether_the_verdict_agrees():
    same = summarize({0: {"pooled": {}, **_population("better", 0.2), "classifier_accuracy": 0.9, "reused": False},
                      1: {"pooled": {}, **_population("better", 0.4), "classifier_accuracy": 0.9, "reused": True}})
    assert same["verdict_same"] and same["differs_on"] == [] and "same for every seed" in same["sentence"]
    assert same["outcomes"] == {"with_uncertainty-model_based / correct_final": {"0": "better", "1": "better"}}
    assert same["held"] == {"with_uncertainty-model_based / correct_final": "better"}
    assert "Held for every seed: With Uncertainty vs Model Based: better on correct ratio." in same["sentence"]
    flip = summarize({0: _population("better", 0.2), 1: _population("not distinguishable", 0.0)})
    assert not flip["verdict_same"] and flip["differs_on"] == ["with_uncertainty-model_based / correct_final"]
    assert flip["held"] == {} and "Held for every seed" not in flip["sentence"]
    assert "differs" in flip["sentence"]
    missing = summarize({0: _population("better", 0.2), 1: {"records": None}})
    assert not missing["verdict_same"] and missing["missing"] == [1]
    json.dumps(flip, allow_nan=False)  # strict JSON


def test_outcomes_come_from_the_records_or_an_older_summarys_verdict_table():
    a, b = _population("better", 0.2), _population("better", 0.35)
    assert outcomes(a) == outcomes(b) == {"with_uncertainty-model_based / correct_final": "better"}
    old = {"verdict_table": [{"comparison": "with_uncertainty-model_based", "metric": "correct_final",
                              "outcome": "worse", "value": -0.2, "ci_low": -0.3, "ci_high": -0.1}]}
    assert outcomes(old) == {"with_uncertainty-model_based / correct_final": "worse"}
    assert outcomes({"records": None}) is None


def test_study_runs_each_seed_then_reuses_finished_ones(tmp_config):
    cfg = tmp_config({"study": {"seeds": [0, 1]}})
    calls: list = []
    ensure = _fake_ensure({0: ("better", 0.2), 1: ("worse", -0.2)}, calls)
    first = run_study(cfg, ensure=ensure)
    assert [c for c in calls if c[1] == "evaluate"] == [("seed-0", "evaluate", 0), ("seed-1", "evaluate", 1)]
    assert [first["per_seed"][s]["reused"] for s in ("0", "1")] == [False, False]
    assert not first["verdict_same"]
    out = cfg.run_dir / "study"
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["per_seed"]["1"]["classifier_accuracy"] == pytest.approx(0.91)
    assert [on_disk["per_seed"][s]["varying_fits"] for s in ("0", "1")] == [2, 2]
    assert [on_disk["per_seed"][s]["varying_fits_at_bound"] for s in ("0", "1")] == [0, 1]
    assert on_disk["per_seed"]["0"]["pooled"]["with_uncertainty"]["correct_final"]["value"] == pytest.approx(0.2)
    page = (out / "index.html").read_text()
    assert "seed 0" in page and "seed 1" in page and "differs" in page
    assert "With Uncertainty vs Model Based, correct ratio, final step" in page  # labels, not keys
    assert "0.910 <small>[0.890, 0.930]</small>" in page  # seed 1's accuracy with its CI
    assert page.index("Verdict per seed") < page.index("Pooled values")
    # viewfuse compare's page over the seed folders, linked from the study page
    assert 'href="compare/index.html"' in page
    cmp = (out / "compare" / "index.html").read_text()
    assert "seed-0" in cmp and "seed-1" in cmp and 'class="changed"' in cmp  # seed 1's verdict flipped
    # The data folder is shared, not rendered again per seed.
    assert (out / "seed-0" / "data").is_symlink()
    assert (out / "seed-0" / "data").resolve() == cfg.stage_dir("data").resolve()
    again = run_study(cfg, ensure=ensure)
    assert [again["per_seed"][s]["reused"] for s in ("0", "1")] == [True, True]
    # What computing each seed cost is still reported after a rerun that reused it.
    assert again["timings_s"]["chain_per_seed"]["1"]["evaluate"] == pytest.approx(2.5)
    assert again["timings_s"]["chain_per_seed"]["1"]["classifier"] is None  # the fake chain wrote no manifest
    assert again["per_seed"] == {s: {**first["per_seed"][s], "reused": True} for s in ("0", "1")}


def test_page_escapes_text():
    s = summarize({0: {**_population("better", 0.1), "records": [_record("better", 0.1, metric="<b>x</b>")]}})
    assert "&lt;b&gt;x&lt;/b&gt;" in render_html(s, "r<1>") and "r&lt;1&gt;" in render_html(s, "r<1>")


def test_the_page_shows_each_seeds_holm_adjusted_verdict_beside_the_unadjusted_one():
    # seed 0: better unadjusted, not distinguishable after Holm; seed 1: better both ways; the pool's
    # records come from the engine (Holm over its primary family)
    holm0 = {"outcome_holm": "not distinguishable", "lo_holm": -0.02, "hi_holm": 0.22, "level_holm": 0.975,
             "p_holm": 0.08, "family": 2}
    holm1 = {"outcome_holm": "better", "lo_holm": 0.05, "hi_holm": 0.4, "level_holm": 0.975, "p_holm": 0.01, "family": 2}
    s = summarize({0: {**_population("better", 0.1), "records": [{**_record("better", 0.1), **holm0}]},
                   1: {**_population("better", 0.2), "records": [{**_record("better", 0.2), **holm1}]}})
    page = render_html(s, "r")
    from reports.shared.records import holm_text
    assert holm_text(holm0).startswith("not distinguishable (97.5 % CI [") and "Holm p" in holm_text(holm0)
    assert f"Holm-adjusted outcome: {holm_text(holm0)}" in page and f"Holm-adjusted outcome: {holm_text(holm1)}" in page
    from reports.study.page import holm_table   # the pooled-over-seeds family, adjusted too
    table = holm_table({"records": [{**_record("better", 0.1), **holm0}, _record("better", 0.3, "nll_final")]})
    assert "Holm-adjusted outcome" in table and holm_text(holm0) in table and "the 2 primary comparisons" in table
    assert table.count("<tr>") == 2 and holm_table({"records": [_record("better", 0.1)]}) == ""
    plain = render_html(summarize({0: _population("better", 0.1)}), "r")
    assert "Holm-adjusted outcome:" not in plain              # no adjusted verdict where the record has none


def _cells(level: float, targets: int = 8) -> list[dict]:
    return [{"target": f"t{t}", "track": k, "setting": "a",
             "values": {"with_uncertainty": {"correct_final": level + 0.01 * ((t * 3 + k) % 5)},
                        "model_based": {"correct_final": level - 0.2 + 0.01 * ((t + k) % 3)}}}
            for t in range(targets) for k in range(3)]


def test_a_pool_over_fewer_than_eight_seeds_has_no_ci_and_the_page_says_why():
    few = summarize({s: {**_population("better", 0.2), "cells": _cells(0.5 + s / 100), "bootstrap": 300}
                     for s in range(3)})
    (r,) = few["pooled_over_seeds"]["records"]
    assert r["outcome"] == "withheld" and r["withheld"].startswith("3 seeds: ")
    page = render_html(few, "r")
    assert "no CI and no verdict (3 seeds, too few units)" in page and "resamples the seeds on top" in page
    assert "these CIs cover" not in page
    enough = summarize({s: {**_population("better", 0.2), "cells": _cells(0.5 + s / 100), "bootstrap": 300}
                        for s in range(8)})
    (r,) = enough["pooled_over_seeds"]["records"]
    assert r["outcome"] == "better" and "resamples the seeds on top" not in render_html(enough, "r")
