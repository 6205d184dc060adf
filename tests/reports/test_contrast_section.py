"""The report's "Instance vs category class models" section (reports/main/contrast.py) renders the
engine's contrast block on a generated population: the arms' values, the difference, the verdict
and the Holm-adjusted verdict as computed, over what the interval varies, and no section without
the arm."""
from types import SimpleNamespace

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.contrast import contrast_block
from reports.main.contrast import contrast_section
from reports.shared.checks import Ledger
from tests.pipeline.evaluation.grid.test_contrast import _ev, _row, _table
from tests.reports.test_power_section import Page


def _ctx(pop):
    sections = []
    return SimpleNamespace(page=Page(), population=pop, ledger=Ledger(),
                           section=lambda title, anchor: sections.append(title)), sections


def test_the_section_shows_each_arm_the_difference_and_both_verdicts():
    block = contrast_block(_ev(), _table(shift=0.3))
    ctx, sections = _ctx({"contrast": block})
    contrast_section(ctx)
    assert sections == ["Instance vs category class models"]
    text = ctx.page.items[0][1]
    assert "With Uncertainty" in text and "correct" in text and "instance level better" in text
    _, header, rows, caption = ctx.page.items[1]
    assert header[4].startswith("instance − category")
    assert "categories, targets and tracks" in caption and "8 categories" in caption and "'category'" in caption
    assert len(rows) == 4                                  # 2 methods x 2 primary metrics
    wu = _row(block, "with_uncertainty", "correct_final")
    first = rows[0]
    assert first[2].value == wu["instance"]["value"] and first[3].value == wu["category"]["value"]
    assert first[4].value == wu["difference"]["value"] and first[4].low == wu["difference"]["lo"]
    assert first[5] == "instance level better" and first[6].startswith("instance level better (")
    assert "Holm p" in first[6]
    mb = next(r for r in rows if r[0] != first[0] and r[1] == first[1])
    assert mb[5] == "not distinguishable" and mb[6].startswith("not distinguishable (")
    explo = ctx.page.items[2]
    assert "exploratory" in explo[3] and all(r[6] == "—" for r in explo[2]) and len(explo[2]) == 2
    assert not ctx.ledger.problems()                       # every label agrees with its printed interval


def test_no_arm_no_section():
    t = _table(shift=0.3)
    ctx, sections = _ctx({"contrast": contrast_block(_ev(), t[t["variant"] == P.DEFAULT])})
    contrast_section(ctx)
    assert sections == [] and ctx.page.items == []


def _withhold(row: dict, why: str) -> None:
    """The row's difference as the engine writes a withheld one: no interval, no (adjusted) verdict."""
    d = row["difference"]
    for k in ("outcome_holm", "lo_holm", "hi_holm", "p_holm", "level_holm", "family"):
        d.pop(k, None)
    d.update(lo=None, hi=None, outcome="withheld", withheld=why)


WHY = "5 scans: a calibrated interval needs at least 8 units of every level the design varies over"


def test_a_sentence_over_the_comparisons_names_the_withheld_ones_and_why():
    from reports.main.contrast import contrast_sentence

    block = contrast_block(_ev(), _table(shift=0.3))
    prim = [r for r in block["rows"] if r["primary"]]
    moved = [r for r in prim if r["difference"]["outcome_holm"] in ("better", "worse")]
    assert moved and len(prim) - len(moved) >= 2
    base = contrast_sentence(block)
    assert base.endswith("every other primary comparison is not distinguishable.")
    # withhold one of the comparisons that was not distinguishable: it is named, with its reason,
    # and the sentence no longer counts it among "every other" comparison
    held = next(r for r in prim if r not in moved)
    _withhold(held, WHY)
    s = contrast_sentence(block)
    assert "every other" not in s and WHY in s and "no CI and no verdict" in s
    name = f"{'With Uncertainty' if held['method'] == 'with_uncertainty' else 'Model Based'}"
    assert f"{name} on" in s.split("no CI")[0].split(";")[-1], s
    assert " are not distinguishable" in s or " is not distinguishable" in s
    # nothing moved, one withheld: no claim that every comparison was tested
    null = contrast_block(_ev(), _table(shift=0.0))
    _withhold(next(r for r in null["rows"] if r["primary"]), WHY)
    s = contrast_sentence(null)
    assert "changes no method's result distinguishably" in s and WHY in s and "On no primary metric" not in s


def test_a_design_with_too_few_units_withholds_every_comparison_and_the_sentence_says_why():
    from reports.main.contrast import contrast_sentence

    t = _table(shift=0.3)
    block = contrast_block(_ev(), t[~t["target"].str.startswith("tomato")])      # 7 categories
    assert all(r["difference"]["outcome"] == "withheld" for r in block["rows"])
    s = contrast_sentence(block)
    assert s.startswith("No primary metric has a verdict") and "all 4 primary comparisons" in s
    assert "7 categories" in s and "not distinguishable" not in s


def test_a_row_with_a_reason_is_worded_withheld_even_where_an_older_summary_kept_a_verdict_beside_it():
    block = contrast_block(_ev(), _table(shift=0.3))
    row = next(r for r in block["rows"] if r["primary"])
    row["difference"].update(lo=None, hi=None, withheld=WHY)    # outcome and Holm outcome left as they were
    ctx, _ = _ctx({"contrast": block})
    contrast_section(ctx)
    _, header, rows, caption = ctx.page.items[1]
    first = rows[0]
    assert first[5] == "no CI, no verdict (too few units)" and first[6] == "—"
    assert not ctx.ledger.problems()
