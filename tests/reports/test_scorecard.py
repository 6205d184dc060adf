"""The claims scorecard reads one statistic per claim (the verdict records, else the paired entry:
both hold the metric spec's statistic) and labels it by its interval; the §5.3 count comes from the
simulate stage's summary in the same run folder."""
from __future__ import annotations

import json
import math

from pipeline.infra.outputs import path as out_path
from reports.main.scorecard import claim_status, simulate_claims, verdict_entry

KEY = "with_uncertainty-model_based"


def test_records_come_first_and_a_null_end_is_unbounded():
    pop = {"records": [{"comparison": KEY, "metric": "log10_mgr95_final", "value": -3.0, "lo": None, "hi": -1.0,
                        "unbounded": True}],
           "paired": {KEY: {"log10_mgr95_final": {"value": 9.0, "ci_low": 1.0, "ci_high": 20.0}}}}
    e = verdict_entry(pop, KEY, "log10_mgr95_final")
    assert e["value"] == -3.0 and e["lo"] == -math.inf and e["hi"] == -1.0
    assert claim_status(e, "log10_mgr95_final") == "holds"          # lower is better, CI below 0


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
