"""A withheld record (too few units of a level the design varies over: ``design.withheld``) is worded
as no CI and no verdict, with its reason, on every page that renders records; never as "not
distinguishable" or "inconclusive" (real.toml's 2 scans did)."""
from __future__ import annotations

from pipeline.evaluation.statistics.records import record
from reports.compare.page import _verdict_text
from reports.main.bottom_line import primary_line
from reports.main.findings import forest
from reports.main.reviewer import evidence_text
from reports.shared.checks import Ledger
from reports.shared.records import clause, interval_text, outcome_clauses, outcome_text, sentence
from reports.study.page import study_sentence

KEY = "with_uncertainty-model_based"
WHY = ("2 scans: a calibrated interval needs at least 8 units of every level the design varies over "
       "(docs/calibration.md)")
UNDECIDED = ("not distinguishable", "inconclusive")


def _rec(metric="correct_final", why=WHY, value=0.0854):
    nan = float("nan")
    return record(KEY, metric, {"value": value, "ci_low": nan, "ci_high": nan}, pooling="mean",
                  better="higher", over=["targets", "scans", "tracks"], n={"targets": 12, "scans": 2, "tracks": 30},
                  primary=True, **({"withheld": why} if why else {}))


def _clean(text: str) -> None:
    assert not any(w in text for w in UNDECIDED), text


def test_the_record_sentence_and_clause_say_no_ci_no_verdict_with_the_reason():
    r = {**_rec(), "loto_flips": ["t3"]}
    assert r["outcome"] == "withheld"
    s = sentence(r)
    assert "changes the outcome" not in s
    assert f"no CI, no verdict: {WHY}" in s and "+0.0854" in s
    _clean(s)
    c = clause(r)
    assert c.endswith(f"no CI, no verdict: {WHY}") and "(withheld)" not in c
    assert interval_text(r) == f"no CI, no verdict: {WHY}"
    assert outcome_text(r) == "no CI, no verdict: 2 scans (too few units)"
    # a record without the reason keeps its outcome word
    assert outcome_text({"outcome": "better"}) == "better"


def test_outcome_clauses_name_withheld_metrics_as_no_verdict():
    all_held = outcome_clauses([_rec(), _rec("log10_mgr95_final")])
    assert len(all_held) == 1 and all_held[0].endswith(": no verdict (no CI: 2 scans, too few units) on any metric")
    _clean(all_held[0])
    tested = record(KEY, "log10_mgr95_final", {"value": -0.5, "ci_low": -0.9, "ci_high": -0.1}, pooling="median",
                    better="lower", over=["targets"], n={"targets": 12}, primary=False)
    mixed = outcome_clauses([_rec(), tested])[0]
    assert "better on log10 MGR" in mixed and "no verdict (no CI: 2 scans, too few units) on correct ratio" in mixed


def test_the_primary_line_does_not_read_a_verdict_off_a_ci_it_lacks():
    line = primary_line({"primary": {"comparison": KEY, "metric": "correct_final", "setting": "all",
                                     "record": {**_rec(), "primary": None}}})
    assert "read off its own 95 % CI" not in line and "no CI, no verdict" in line and "no verdict" in line
    _clean(line)


def test_the_forest_alt_text_words_a_withheld_record_without_a_verdict():
    r = _rec()
    pop = {"paired": {KEY: {"correct_final": {"value": r["value"]}}}, "records": [r], "paired_per_target": {}}
    led = Ledger()
    alt = forest(pop, led)
    assert "no CI, no verdict" in alt
    _clean(alt)
    assert led.problems() == []


def test_the_study_sentence_says_no_seed_reaches_a_verdict_when_every_entry_is_withheld():
    text = study_sentence([1, 2], [], [], 2, {f"{KEY} / correct_final": "withheld",
                                              f"{KEY} / log10_mgr95_final": "withheld"})
    assert "No seed" in text and "withheld" in text and "same for every seed" not in text


def test_the_compare_cell_words_a_withheld_verdict():
    cell = _verdict_text({"outcome": "withheld", "withheld": WHY, "value": 0.0854, "ci_low": None, "ci_high": None})
    assert cell.startswith("no CI, no verdict: 2 scans")
    _clean(cell)


def test_the_limitations_sentence_follows_the_design():
    held = evidence_text({"records": [_rec(), _rec("log10_mgr95_final")]}, 12, ["s1", "s2"])
    assert "vary over" not in held and "no CI and no verdict" in held and "2 scans" in held and "all 2" in held
    tested = record(KEY, "correct_final", {"value": 0.1, "ci_low": 0.0, "ci_high": 0.2}, pooling="mean",
                    better="higher", over=["targets", "tracks"], n={"targets": 12}, primary=True)
    free = evidence_text({"records": [tested], "cluster": "target"}, 12, ["s1"])
    assert "the intervals vary over" in free and "no CI" not in free


def _tested(metric="log10_mgr95_final"):
    return record(KEY, metric, {"value": -0.5, "ci_low": -0.9, "ci_high": -0.1}, pooling="median",
                  better="lower", over=["targets", "tracks"], n={"targets": 12, "tracks": 30}, primary=True)


def test_the_bottom_lines_summary_counts_the_withheld_differences_apart_with_why():
    from reports.main.bottom_line import bottom_line

    pop = {"records": [_rec(), _tested()], "n_targets": 12}
    second = bottom_line(pop)[-1]
    assert second.startswith("1 of these 2 differences carries no CI and no verdict (2 scans, too few units); "
                             "each other outcome is read off"), second
    every = bottom_line({"records": [_rec(), _rec("log10_mgr95_final")], "n_targets": 12})
    assert every[-1].startswith("No difference here has a CI or a verdict (2 scans, too few units)")
    assert "read off" not in every[-1] and "varies over" not in every[-1]
    _clean(" ".join(every))
    tested = bottom_line({"records": [_tested()], "n_targets": 12})[-1]
    assert tested.startswith("Each outcome is read off the 95 % CI") and "no CI" not in tested


def test_the_study_sentence_counts_entries_withheld_in_every_seed_apart():
    held = {f"{KEY} / correct_final": "withheld", f"{KEY} / log10_mgr95_final": "better"}
    text = study_sentence([1, 2], [], [], 2, held)
    assert "1 of 2 entries carries no CI and no verdict in every seed" in text
    assert "Held for every seed" in text and "better on log10 MGR" in text
    assert "no CI" not in study_sentence([1, 2], [], [], 1, {f"{KEY} / log10_mgr95_final": "better"})
