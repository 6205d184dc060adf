"""``viewfuse compare``: N runs side by side from their summary.json and manifests only."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from pipeline.evaluation.statistics.engine import seed_block
from reports.compare.page import build_page, render_text
from reports.compare.runs import CompareError, compare
from stages.commands.cli import main

METHODS = ("with_uncertainty", "model_based", "simple_bayes")
KEY = "with_uncertainty-model_based"


def _est(v: float, w: float = 0.1) -> dict:
    return {"value": v, "ci_low": v - w, "ci_high": v + w}


def write_run(d: Path, *, correct: float = 0.6, mgr: float = 2.0, outcome: str = "better", sigmas=(0.1, 0.3),
              seed: int = 0, table: bool = True, population: bool = True, cells: bool = True) -> Path:
    """A finished run as compare reads it: evaluate/summary.json and stage manifests; its cells
    (4 targets x 3 tracks) hold every method's values constant at the pooled ones, With
    Uncertainty ahead of Model Based by 0.2 in correct ratio when ``outcome`` is better (behind
    when worse)."""
    pop = {"pooled": {m: {"correct_final": _est(correct - 0.1 * i), "log10_mgr95_final": _est(mgr + i)}
                      for i, m in enumerate(METHODS)},
           "paired": {KEY: {"correct_final": {**_est(0.2 if outcome == "better" else 0.0), "better": "higher"},
                            "log10_mgr95_final": {**_est(-1.0, 0.5), "better": "lower"}}}}
    if table:
        pop["verdict_table"] = [{"comparison": KEY, "metric": "correct_final", "outcome": outcome,
                                 **pop["paired"][KEY]["correct_final"]},
                                {"comparison": KEY, "metric": "log10_mgr95_final", "outcome": "better",
                                 **pop["paired"][KEY]["log10_mgr95_final"]}]
    if cells:
        gap = {"better": 0.2, "worse": -0.2}.get(outcome, 0.0)
        vals = {m: {"correct_final": correct - 0.1 * i, "log10_mgr95_final": mgr + i} for i, m in enumerate(METHODS)}
        vals["model_based"]["correct_final"] = correct - gap
        pop["cells"] = [{"target": f"t{t}", "track": j, "setting": "s", "values": vals} for t in range(4) for j in range(3)]
        pop["bootstrap"] = 300
    (d / "evaluate").mkdir(parents=True, exist_ok=True)
    summary = {"population": pop} if population else {"experiments": {}, "target": "x"}
    (d / "evaluate" / "summary.json").write_text(json.dumps(summary))
    sections = {"classifier": {"classifier": {"seed": seed, "epochs": 7}},
                "evaluate": {"evaluate": {"seed": 0, "randomized": {"sigmas_m": list(sigmas), "realizations": 20}}},
                "models": {"models": {"component_rule": "top_mean"}, "evaluate.n_candidates": 4}}
    for stage in ("data", "classifier", "features", "models", "evaluate"):
        (d / stage).mkdir(parents=True, exist_ok=True)
        (d / stage / "manifest.json").write_text(json.dumps({"stage": stage, "parts": {"sections": sections.get(stage, {})}}))
    return d


def test_one_run_has_no_config_diff_and_says_there_is_nothing_to_compare(tmp_path):
    c = compare([write_run(tmp_path / "a")])
    assert c.config == {} and len(c.columns) == 1
    text = render_text(c)
    assert "nothing to compare against" in text and "0.60 [0.50, 0.70]" in text


def test_two_runs_show_only_the_changed_key_and_mark_changed_outcomes(tmp_path):
    a = write_run(tmp_path / "synthetic")
    b = write_run(tmp_path / "b", sigmas=(0.2,), outcome="not distinguishable", correct=0.5)
    c = compare([a, b])
    assert c.config == {"evaluate.randomized.sigmas_m": [[0.1, 0.3], [0.2]]}   # only the key that changed
    assert c.changed[(KEY, "correct_final")] == [False, True]
    assert c.changed[(KEY, "log10_mgr95_final")] == [False, False]
    assert [e["value"] for e in c.pooled[("with_uncertainty", "correct_final")]] == [0.6, 0.5]
    text = render_text(c)
    assert "evaluate.randomized.sigmas_m  [0.1, 0.3]  [0.2]" in text
    assert "*not distinguishable" in text and "*better" not in text
    html = build_page(c).render()
    assert html.count('class="changed"') == 1 and "evaluate.randomized.sigmas_m" in html
    assert html.count("evaluate.seed") == 0        # unchanged keys stay out


def test_three_runs_with_a_seed_group_pool_over_seeds(tmp_path):
    base = write_run(tmp_path / "synthetic", correct=0.7)
    study = tmp_path / "study"
    for s, (cv, mg) in enumerate(((0.6, 2.0), (0.5, 40.0), (0.7, 3.0))):
        write_run(study / f"seed-{s}", correct=cv, mgr=mg, seed=s, outcome="better" if s != 1 else "worse")
    c = compare([base, study])
    names = [col.name for col in c.columns]
    assert names == ["synthetic", "study/seed-0", "study/seed-1", "study/seed-2", "study: pooled over 3 seeds"]
    assert c.config == {"classifier.seed": [0, 0, 1, 2]}
    # the seed group is pooled by the engine (seeds -> targets -> tracks), as `viewfuse study` does
    pooled = c.pooled[("with_uncertainty", "correct_final")][-1]
    # 3 seeds on top of the draws: too few for a calibrated interval, as any level (design.withheld)
    assert pooled["value"] == pytest.approx(0.6) and math.isnan(pooled["ci_low"]) and math.isnan(pooled["ci_high"])
    assert pooled["withheld"].startswith("3 seeds, 4 targets: a calibrated interval needs at least 8 units")
    assert pooled["over"] == ["seeds", "targets", "tracks"] and pooled["n"]["seeds"] == 3
    runs = [json.loads((study / f"seed-{s}" / "evaluate" / "summary.json").read_text())["population"] for s in range(3)]
    same = seed_block({f"study/seed-{s}": p["cells"] for s, p in enumerate(runs)}, list(METHODS),
                      ["correct_final", "log10_mgr95_final"], [("with_uncertainty", "model_based"),
                                                               ("with_uncertainty", "simple_bayes")], 300)
    assert _same(pooled, same["pooled"]["with_uncertainty"]["correct_final"])
    mgr = c.pooled[("with_uncertainty", "log10_mgr95_final")][-1]
    assert mgr["pooling"] == "median" and mgr["value"] == pytest.approx((2.0 + 40.0 + 3.0) / 3)  # mean of seeds' medians
    v = c.verdicts[(KEY, "correct_final")][-1]
    assert v["outcome"] == "withheld" and not v["held_for_every_seed"]   # +0.2, -0.2, +0.2 over 3 seeds: no CI
    assert v["per_seed"] == "better ×2, worse ×1"
    assert c.changed[(KEY, "correct_final")] == [False, False, True, False, True]
    # `viewfuse study` pools the same seeds with the same function: the same numbers
    from stages.commands.study import summarize

    study_pool = summarize({s: {**p, "records": None} for s, p in enumerate(runs)})["pooled_over_seeds"]
    from reports.shared.records import pool_note

    note = pool_note(c.columns[-1].pool)
    assert "no CI and no verdict (3 seeds, 4 targets, too few units)" in note and "resamples the seeds on top" in note
    assert _same(study_pool["pooled"], c.columns[-1].pool["pooled"])
    assert _same(study_pool["records"], c.columns[-1].pool["records"])


def _same(a, b) -> bool:
    """Equal, a withheld interval's NaN ends included."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_a_seed_group_without_cells_has_no_pooled_value(tmp_path):
    study = tmp_path / "study"
    for s in range(2):
        write_run(study / f"seed-{s}", seed=s, cells=False)
    c = compare([study])
    assert c.pooled[("with_uncertainty", "correct_final")][-1] is None
    assert c.verdicts[(KEY, "correct_final")][-1]["outcome"].startswith("no pooled value")


def test_a_missing_run_is_named(tmp_path, capsys):
    a = write_run(tmp_path / "a")
    with pytest.raises(CompareError, match=r"run .*nope.*not found"):
        compare([a, tmp_path / "nope"])
    half = tmp_path / "half"
    (half / "models").mkdir(parents=True)        # a run whose evaluate stage never finished
    with pytest.raises(CompareError, match=r"run half: .*summary.json not found"):
        compare([half])
    assert main(["compare", str(a), str(tmp_path / "nope")]) == 1
    assert "nope" in capsys.readouterr().err


def test_an_older_summary_is_named_or_read_from_its_paired_cis(tmp_path):
    old = write_run(tmp_path / "old", population=False)
    with pytest.raises(CompareError, match=r"run old: .*no 'population'.*older evaluate stage"):
        compare([write_run(tmp_path / "a"), old])
    no_table = write_run(tmp_path / "no_table", table=False)
    c = compare([write_run(tmp_path / "a"), no_table])
    assert [v["outcome"] for v in c.verdicts[(KEY, "correct_final")]] == ["better", "better"]
    assert [v["outcome"] for v in c.verdicts[(KEY, "log10_mgr95_final")]] == ["better", "better"]
    assert any("older summary format" in n for n in c.notes)


def test_cli_prints_the_table_and_writes_the_page(tmp_path, capsys):
    a, b = write_run(tmp_path / "synthetic"), write_run(tmp_path / "b", sigmas=(0.2,))
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert "Config keys that differ:" in out and "evaluate.randomized.sigmas_m" in out
    page = (tmp_path / "cmp" / "index.html").read_text()
    assert '<th scope="col">synthetic</th>' in page and "Paired verdicts" in page


def test_three_plain_runs_are_three_columns_and_each_changed_key_is_listed_once(tmp_path):
    a = write_run(tmp_path / "a")
    b = write_run(tmp_path / "b", sigmas=(0.2,))
    c3 = write_run(tmp_path / "c", seed=4, outcome="worse")
    c = compare([a, b, c3])
    assert [col.name for col in c.columns] == ["a", "b", "c"] and not any(col.pooled_over_seeds for col in c.columns)
    assert c.config == {"classifier.seed": [0, 0, 4], "evaluate.randomized.sigmas_m": [[0.1, 0.3], [0.2], [0.1, 0.3]]}
    assert c.changed[(KEY, "correct_final")] == [False, False, True]


def test_an_older_summary_with_an_unbounded_end_follows_the_records_outcome_rule(tmp_path):
    """A paired CI with a null (infinite) end is read by the one outcome rule: unbounded on the good
    side still lies wholly above 0; unbounded towards 0 cannot."""
    run = write_run(tmp_path / "old", table=False)
    path = run / "evaluate" / "summary.json"
    s = json.loads(path.read_text())
    s["population"]["paired"][KEY]["correct_final"] = {"value": 0.3, "ci_low": 0.1, "ci_high": None}
    s["population"]["paired"][KEY]["log10_mgr95_final"] = {"value": -1.0, "ci_low": None, "ci_high": 0.5}
    path.write_text(json.dumps(s))
    v = compare([run]).verdicts
    assert v[(KEY, "correct_final")][0]["outcome"] == "better"
    assert v[(KEY, "log10_mgr95_final")][0]["outcome"] == "not distinguishable"


def test_the_paired_verdicts_show_the_holm_adjusted_outcome_beside_the_unadjusted_one(tmp_path):
    def with_records(d, holm):
        path = d / "evaluate" / "summary.json"
        summary = json.loads(path.read_text())
        pop = summary["population"]
        pop["records"] = [{**r, "lo": r["ci_low"], "hi": r["ci_high"], "primary": r["metric"] == "correct_final",
                           **(holm if r["metric"] == "correct_final" else {})} for r in pop.pop("verdict_table")]
        path.write_text(json.dumps(summary))
        return d

    nd = {"outcome_holm": "not distinguishable", "lo_holm": -0.01, "hi_holm": 0.31, "level_holm": 0.975,
          "p_holm": 0.06, "family": 2}
    a = with_records(write_run(tmp_path / "a"), {**nd, "outcome_holm": "better", "lo_holm": 0.05})
    b = with_records(write_run(tmp_path / "b"), nd)
    c = compare([a, b])
    row = c.verdicts[(KEY, "correct_final")]
    assert [v["outcome"] for v in row] == ["better", "better"]
    assert [v["outcome_holm"] for v in row] == ["better", "not distinguishable"]
    assert c.changed[(KEY, "correct_final")] == [False, True]         # the adjusted verdict changed
    assert "outcome_holm" not in c.verdicts[(KEY, "log10_mgr95_final")][0]   # exploratory: unadjusted only
    text = render_text(c)
    from reports.shared.records import holm_text
    assert f"Holm-adjusted outcome: {holm_text(nd)}" in text and holm_text(nd).startswith("not distinguishable (97.5 %")
    html = build_page(c).render()
    assert "Holm-adjusted outcome: better (97.5 % CI" in html and "Holm-adjusted outcome: not distinguishable" in html
