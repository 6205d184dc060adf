"""The verdict renderer's short and multi-record forms (alt text, ablation cells, bottom line,
seed study) say what the records say: the same value, interval and outcome as the full sentence."""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.statistics.records import outcome, record
from reports.main.bottom_line import bottom_line
from reports.main.findings import forest
from reports.shared.checks import Ledger
from reports.shared.numbers import fmt
from reports.shared.records import clause, interval_text, outcome_clauses, sentence
from reports.study.page import study_sentence

WU_MB, WU_SB = "with_uncertainty-model_based", "with_uncertainty-simple_bayes"
METRICS = ("correct_final", "log10_mgr95_final", "log10_mgr75_final")


def _population(seed: int = 0) -> dict:
    """Paired estimates drawn at random, and their records built by the statistics' own constructor."""
    rng = np.random.default_rng(seed)
    paired, recs, ppt = {}, [], {}
    for key in (WU_MB, WU_SB):
        for metric in METRICS:
            v = float(rng.normal(0, 0.3))
            half = float(rng.uniform(0.05, 0.4))
            est = {"value": v, "ci_low": v - half, "ci_high": v + half}
            paired.setdefault(key, {})[metric] = est
            better = "lower" if metric.startswith("log10") else "higher"
            recs.append(record(key, metric, est, pooling="mean", better=better, over=["targets", "tracks"],
                               n={"targets": 3, "tracks": 9}, primary=metric == "correct_final"))
            ppt.setdefault(key, {})["t0"] = {metric: est}
    return {"paired": paired, "records": recs, "paired_per_target": ppt, "n_targets": 3, "n_tracks": 9}


def test_the_forest_alt_text_words_each_record_with_its_own_value_interval_and_outcome():
    for seed in range(4):
        pop = _population(seed)
        led = Ledger()
        alt = forest(pop, led)
        for r in pop["records"]:
            if r["metric"] not in ("correct_final", "log10_mgr95_final"):
                assert clause(r) not in alt
                continue
            assert clause(r) in alt
            assert f"{fmt(r['value'], signed=True)}, {interval_text(r)} ({r['outcome']})" in clause(r)
            assert r["outcome"] == outcome(r["lo"], r["hi"], r["better"] == "higher")
        assert led.problems() == []
        assert {e.label for e in led.entries} <= {"better", "worse", "not distinguishable"}
        assert len(led.entries) == 4


def test_the_clause_and_the_sentence_state_the_same_statistic():
    for r in _population(1)["records"]:
        c, s = clause(r), sentence(r)
        assert fmt(r["value"], signed=True) in s and interval_text(r) in s and interval_text(r) in c


def test_outcome_clauses_group_a_comparison_and_follow_the_records():
    pop = _population(2)
    for r in pop["records"]:      # make the outcomes known: WU-MB better on both MGR entries, not on correct
        if r["comparison"] == WU_MB:
            r["outcome"] = "not distinguishable" if r["metric"] == "correct_final" else "better"
        else:
            r["outcome"] = "not distinguishable"
    mb, sb = outcome_clauses(pop["records"])
    assert mb == "With Uncertainty vs Model Based: better on log10 MGR; not distinguishable on correct ratio"
    assert sb == "With Uncertainty is not distinguishable from Simple Bayes on any metric"
    (bare,) = outcome_clauses([r for r in pop["records"] if r["comparison"] == WU_MB], subject=False)
    assert bare == mb.split(": ", 1)[1]
    pop["records"][0]["outcome"] = "worse"
    assert outcome_clauses(pop["records"])[0] != mb
    first = bottom_line(pop)[0]
    assert "With Uncertainty vs Model Based: worse on correct ratio" in first


def test_the_study_sentence_words_the_held_outcomes_as_the_records_do():
    held = {f"{WU_MB} / correct_final": "better", f"{WU_MB} / log10_mgr95_final": "not distinguishable"}
    text = study_sentence([0, 1], [], [], 2, held)
    assert text.startswith("The verdict is the same for every seed (0, 1).")
    recs = [{"comparison": WU_MB, "metric": "correct_final", "outcome": "better"}]
    assert text.endswith("Held for every seed: " + outcome_clauses(recs)[0] + ".")
    assert "Held" not in study_sentence([0, 1], [1], [], 2, held)


def test_the_sentence_and_the_bottom_line_say_over_what_each_clustering_varies():
    est = {"value": 0.05, "ci_low": 0.01, "ci_high": 0.09}
    cases = {"category": (["categories", "targets", "tracks"], {"categories": 8, "targets": 72, "tracks": 144},
                          "8 categories × 72 targets × 144 tracks", "mean over categories of their targets'"),
             "crossed": (["targets", "scans"], {"targets": 75, "scans": 15, "tracks": 600},
                         "75 targets crossed with 15 scans", "mean over targets of the differences"),
             "target": (["targets", "tracks"], {"targets": 12, "tracks": 96}, "12 targets × 96 tracks",
                        "mean over targets of the differences")}
    for cluster, (over, n, words, stat) in cases.items():
        r = record(WU_MB, "correct_final", est, pooling="mean", better="higher", over=over, n=n, primary=True,
                   cluster=cluster)
        s = sentence(r)
        assert f"over {words}" in s and stat in s, s
        second = bottom_line({"records": [r], "n_targets": n["targets"]})[1]
        levels = {"category": "categories, targets and tracks", "crossed": "targets and scans, crossed",
                  "target": "targets and tracks"}[cluster]
        assert f"varies over {levels} only" in second, second



def test_what_the_intervals_vary_over_follows_the_design():
    # the scorecard and the reviewer's note read it from the summary: a crossed or clustered run
    # must not say "targets and tracks"
    from reports.shared.records import varies_text

    assert varies_text({"cluster": "crossed", "records": []}) == "targets and scans, crossed"
    assert varies_text({"cluster": "category"}) == "categories, targets and tracks"
    assert varies_text({}) == "targets and tracks"


def test_the_declared_primary_record_says_it_is_tested_alone():
    from pipeline.evaluation.statistics.multiplicity import holm

    pop = _population(2)
    recs = [r for r in pop["records"] if r["metric"] == "correct_final"]
    draws = {(r["comparison"], r["metric"]): None for r in recs}
    holm(recs, draws, exclude={(WU_MB, "correct_final")})
    declared, other = recs
    assert "tested alone" in sentence(declared) and "tested alone" not in sentence(other)
    assert other["family"] == 1 and "family" not in declared
