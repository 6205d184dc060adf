"""The claims scorecard reads one statistic per claim (the verdict records, else the paired entry:
both hold the metric spec's statistic) and labels it by its interval; the §5.3 count comes from the
simulate stage's summary in the same run folder."""
from __future__ import annotations

import json
import math
from pathlib import Path

from pipeline.infra.outputs import path as out_path
from reports.main.scorecard import claim_status, simulate_claims, verdict_entry, verdict_word, withheld_status

KEY = "with_uncertainty-model_based"


def test_records_come_first_and_a_null_end_is_unbounded():
    pop = {"records": [{"comparison": KEY, "metric": "log10_mgr95_final", "value": -3.0, "lo": None, "hi": -1.0,
                        "unbounded": True}],
           "paired": {KEY: {"log10_mgr95_final": {"value": 9.0, "ci_low": 1.0, "ci_high": 20.0}}}}
    e = verdict_entry(pop, KEY, "log10_mgr95_final")
    assert e["value"] == -3.0 and e["lo"] == -math.inf and e["hi"] == -1.0
    assert claim_status(e, "log10_mgr95_final") == "holds"          # lower is better, CI below 0


def test_a_withheld_interval_has_no_holm_interval_and_no_verdict():
    # too few clusters: the engine gives no interval (JSON null, not unbounded), no Holm step, and
    # the scorecard says so instead of "inconclusive" (real.toml's 2 scans printed "+0.0854 inconclusive")
    pop = {"records": [{"comparison": KEY, "metric": "correct_final", "value": 0.0854, "lo": None, "hi": None,
                        "unbounded": False, "withheld": "2 scans: too few", "outcome": "withheld"}]}
    e = verdict_entry(pop, KEY, "correct_final")
    assert "holm" not in e and (e["lo"], e["hi"]) == (None, None)
    status = withheld_status(e)
    assert status == "no verdict: no CI: 2 scans: too few" and "inconclusive" not in status
    assert verdict_word(status, True) == verdict_word(status, False) == status
    assert withheld_status(verdict_entry({"records": [{**pop["records"][0], "withheld": None, "lo": 0.01,
                                                        "hi": 0.2}]}, KEY, "correct_final")) == ""


def test_without_records_the_paired_entry_is_read():
    pop = {"paired": {KEY: {"nll_final": {"value": -2.0, "ci_low": -5.0, "ci_high": 0.5}}}}
    e = verdict_entry(pop, KEY, "nll_final")
    assert (e["value"], e["lo"], e["hi"]) == (-2.0, -5.0, 0.5)
    assert claim_status(e, "nll_final") == "inconclusive"
    pop["paired"][KEY]["correct_final"] = {"value": -0.2, "ci_low": -0.3, "ci_high": -0.1}
    assert claim_status(verdict_entry(pop, KEY, "correct_final"), "correct_final") == "fails"
    assert claim_status(verdict_entry(pop, KEY, "msde_final"), "msde_final") == "not measured"


def test_simulate_claims_are_read_from_the_run_folder(tmp_path):
    assert simulate_claims(tmp_path) == []
    p = out_path(tmp_path / "simulate", "simulate", "summary")
    p.parent.mkdir(parents=True)
    p.write_text(json.dumps({"claims": [{"key": "a", "holds": True, "ci_side": "holds"},
                                        {"key": "b", "holds": False, "ci_side": "spans"}]}))
    assert [c["key"] for c in simulate_claims(tmp_path)] == ["a", "b"]


def test_the_similar_claim_is_read_as_equivalence_within_the_margin():
    from pipeline.evaluation.statistics.records import equivalence
    from reports.main.scorecard import equivalence_margin, equivalence_status

    assert equivalence(-0.03, 0.04, 0.05) == "equivalent"           # whole CI inside ±margin
    assert equivalence(-0.03, 0.06, 0.05) == "not distinguishable"  # crosses +margin
    assert equivalence(0.07, 0.20, 0.05) == "different"            # wholly beyond +margin
    assert equivalence(-0.30, -0.06, 0.05) == "different"          # wholly below -margin
    assert equivalence(None, 0.01, 0.05) == "not distinguishable"  # unbounded end
    assert equivalence(float("nan"), 0.01, 0.05) == "not distinguishable"
    entry = {"value": 0.01, "lo": -0.02, "hi": 0.04}
    assert equivalence_status(entry, 0.05) == "holds"
    assert equivalence_status(entry, 0.03) == "inconclusive"       # the margin in the config decides
    assert equivalence_status({"value": 0.2, "lo": 0.1, "hi": 0.3}, 0.05) == "fails"
    assert equivalence_status(None, 0.05) == "not measured"
    assert equivalence_margin({"report": {"equivalence_margin_correct": 0.1}}) == 0.1
    assert equivalence_margin({}) == 0.05


def test_the_paper_column_names_sections_and_converts_mgr_to_log10():
    import re

    from pipeline.evaluation.metrics.paper import CLAIMS, NUMBERS, log10_of_ln
    from reports.main.scorecard import paper_cell

    numbers = (Path(__file__).resolve().parents[3] / "shared" / "paper" / "numbers.md")
    assert {c.key for c in CLAIMS} == set(NUMBERS)
    for c in CLAIMS:
        cell = paper_cell(c)
        assert cell and all(n.section in cell for n in c.paper)
        assert all(re.match(r"§\d", n.section) for n in c.paper)
    assert next(c for c in CLAIMS if c.metric == "correct_final" and c.baseline == "model_based").reading == "equivalence"
    mgr = NUMBERS["milder_worst_cases"][0]     # Table 1: 629.2 and 2.46 on the paper's natural-log scale
    assert abs(mgr.difference - (2.46 - 629.2) / math.log(10)) < 1e-9
    assert abs(log10_of_ln(math.log(1000.0)) - 3.0) < 1e-12
    assert "273" in mgr.text and "1.07" in mgr.text                 # log10 values, with the paper's own beside
    if numbers.is_file():   # the transcription the values come from (beside the clone, when present)
        text = numbers.read_text()
        for raw in ("629.2", "2.46", "48.6", "0.74", "0.76", "0.66", "0.72", "0.958", "10 %"):
            assert raw in text, raw


def test_a_primary_family_record_is_judged_by_its_holm_interval_and_the_bottom_line_reads_it():
    from reports.main.bottom_line import bottom_line

    rec = {"comparison": KEY, "method": "with_uncertainty", "baseline": "model_based", "metric": "correct_final",
           "value": 0.05, "lo": 0.01, "hi": 0.09, "unbounded": False, "better": "higher", "outcome": "better",
           "primary": True, "pooling": "mean", "over": ["targets", "tracks"], "n": {"targets": 9, "tracks": 18},
           "family": 4, "level_holm": 1 - 0.05 / 4, "lo_holm": -0.01, "hi_holm": 0.11,
           "outcome_holm": "not distinguishable", "p": 0.02, "p_holm": 0.08}
    pop = {"records": [rec]}
    e = verdict_entry(pop, KEY, "correct_final")
    assert (e["lo"], e["hi"]) == (0.01, 0.09) and e["holm"] == (-0.01, 0.11)
    assert claim_status(e, "correct_final") == "inconclusive"       # unadjusted it would hold
    first = bottom_line(pop)[0]
    assert "not distinguishable" in first and "better" not in first and "Holm-adjusted over the 4" in first


class _Page:
    """Records what the scorecard writes: (kind, header or text, rows)."""
    def __init__(self):
        self.tables, self.paragraphs = [], []

    def table(self, header, rows, **kw):
        self.tables.append((list(header), rows, kw.get("caption", "")))

    def paragraph(self, text, **kw):
        self.paragraphs.append(text)


def _scorecard_on(config: dict, extra: dict | None = None):
    """The scorecard of a population whose every comparison is clearly against the claim."""
    from types import SimpleNamespace

    from reports.main.scorecard import scorecard
    from reports.shared.checks import Ledger

    recs = [{"comparison": "with_uncertainty-model_based", "metric": "confident_error_final", "value": 0.2,
             "lo": 0.1, "hi": 0.3},
            {"comparison": "with_uncertainty-model_based", "metric": "correct_final", "value": -0.3,
             "lo": -0.4, "hi": -0.2},
            {"comparison": "with_uncertainty-model_based", "metric": "log10_mgr95_final", "value": 2.0,
             "lo": 1.0, "hi": 3.0},
            {"comparison": "with_uncertainty-simple_bayes", "metric": "correct_final", "value": -0.2,
             "lo": -0.3, "hi": -0.1}]
    page = _Page()
    ctx = SimpleNamespace(population={"records": recs, **(extra or {})}, config=config, ledger=Ledger(), page=page,
                          run=SimpleNamespace(run_dir=None))
    scorecard(ctx)
    return page


def _verdicts(table) -> list[str]:
    header, rows, _ = table
    return [str(r[-1]) for r in rows]


def test_run_setting_is_computed_from_the_config():
    from pipeline.evaluation.metrics.paper import run_setting

    assert run_setting({"data": {"source": "synthetic"}}) == "synthetic"
    assert run_setting({}) == "synthetic"
    assert run_setting({"data": {"source": "real_imagery", "real_imagery": {"dataset": "coil"}}}) == "real_instance"
    assert run_setting({"data": {"source": "real"}}) == "real_instance"
    assert run_setting({"data": {"source": "real_imagery", "real_imagery": {"dataset": "eth80"}}}) == "real_category"


def test_on_synthetic_data_the_paper_claims_fail_and_simple_bayes_is_a_question():
    page = _scorecard_on({"data": {"source": "synthetic"}})
    ours, beyond = page.tables
    assert ours[0][0] == "claim of the paper (in our words)" and beyond[0][0] == "question beyond the paper"
    assert _verdicts(ours) == ["fails", "fails", "fails"]          # made in simulation / rendered scenes
    assert _verdicts(beyond)[1] == "not supported in this setting"   # Simple Bayes: no claim of the paper
    assert _verdicts(beyond)[0].startswith("not tested here")         # §5.5: no such test in this summary
    assert all("“" in r[1] and "§" in r[1] for r in ours[1])       # section and quote on every claim


def test_at_category_level_no_claim_of_the_paper_fails():
    page = _scorecard_on({"data": {"source": "real_imagery", "real_imagery": {"dataset": "eth80"}}})
    assert len(page.tables) == 1                                    # only questions beyond the paper
    header, rows, caption = page.tables[0]
    assert header[0] == "question beyond the paper" and len(rows) == 5
    assert {v.split(" (")[0] for v in _verdicts(page.tables[0])} == {"not supported in this setting", "not tested here"}
    text = " ".join(str(c) for r in rows for c in r) + caption + " ".join(page.paragraphs)
    assert "fails" not in text and "category level" in text
    assert any("none was made in this run's setting" in p for p in page.paragraphs)


def test_on_real_instances_only_the_claims_made_on_real_images_are_the_papers():
    page = _scorecard_on({"data": {"source": "real_imagery", "real_imagery": {"dataset": "coil"}}})
    ours, beyond = page.tables
    assert [r[0].split(" ")[0] for r in ours[1]] == ["Modelling", "On"]   # correct_similar, paper_55
    assert "§5.5.2" in ours[1][1][1] and "in most cases both methods eventually deduce" in ours[1][1][1]
    assert "we validate our contribution" not in " ".join(str(c) for r in ours[1] for c in r)   # not the abstract
    assert any("real model uncertainty" in r[1] for r in beyond[1])       # MGR, confident errors: made in §5.3-5.4
    assert all(v.endswith("in this setting") for v in _verdicts(beyond))


def _paper_55(record=None, missing="", width=0.5):
    rec = record
    return {"paper_55": {"comparison": "with_uncertainty_poses_only-model_based", "metric": "wrong10_final",
                         "setting": "biased_randomized", "record": rec, **({"missing": missing} if missing else {}),
                         "mgr": {"all": {"paired": {"with_uncertainty-model_based": {
                             "p95": {"value": -0.1, "ci_low": -0.1 - width / 2, "ci_high": -0.1 + width / 2},
                             "verdict": None if width > 1 else "not distinguishable",
                             **({"no_verdict": f"the 95 % CI spans {width:g} decades"} if width > 1 else {})}}}}}}


def test_the_55_row_reads_poses_only_on_the_ten_times_event_in_its_setting():
    coil = {"data": {"source": "real_imagery", "real_imagery": {"dataset": "coil"}}}
    rec = {"comparison": "with_uncertainty_poses_only-model_based", "metric": "wrong10_final", "value": -0.08,
           "lo": -0.12, "hi": -0.03, "n": {"targets": 75}, "over": ["targets", "scans"]}
    ours, _ = _scorecard_on(coil, _paper_55(rec)).tables
    row = ours[1][1]
    assert row[4].value == -0.08 and row[-1] == "holds" and "poses-only variant − Model Based" in row[2]
    missing = _scorecard_on(coil, _paper_55(None, "the run has no 'biased_randomized' setting")).tables[0][1][1]
    assert missing[-1] == "not tested here (the run has no 'biased_randomized' setting)" and missing[4].value is None


def test_an_mgr_interval_spanning_decades_gives_no_verdict():
    ours, _ = _scorecard_on({"data": {"source": "synthetic"}}, _paper_55(width=30.6)).tables
    mgr = ours[1][2]
    assert mgr[-1] == "no verdict: the 95 % CI spans 30.6 decades" and mgr[4].value == -0.1
    ours, _ = _scorecard_on({"data": {"source": "synthetic"}}, _paper_55(width=0.5)).tables
    assert ours[1][2][-1] == "inconclusive"


def test_one_declaration_serves_the_simulation_and_the_scorecard():
    from pipeline.evaluation.metrics import paper
    from pipeline.evaluation.simulation import claims as CL

    assert [c.key for c in CL.CLAIMS] == [c.key for c in paper.SIMULATION_CLAIMS]
    for spec, decl in zip(CL.CLAIMS, paper.SIMULATION_CLAIMS):
        assert (spec.statement, spec.op, spec.threshold, spec.section) == (decl.statement, decl.op,
                                                                           decl.threshold, decl.section)
    assert all(c.section.startswith("§") and c.quote and c.question for c in paper.CLAIMS)
    assert all(c.unclaimed for c in paper.CLAIMS if not c.made_in)
    assert all(set(c.made_in) <= set(paper.MADE_IN) for c in paper.CLAIMS + paper.SIMULATION_CLAIMS)
