"""The report's Power section and the paper's §5.5 setting (reports/main/power.py), from a
population's ``power`` block and ``by_setting`` entries (nothing recomputed)."""
from types import SimpleNamespace

from pipeline.evaluation.statistics.power import power_block
from reports.main.power import paper_setting, power_section, power_sentence, priced


class Page:
    def __init__(self):
        self.items = []

    def paragraph(self, text, cls=""):
        self.items.append(("p", text))

    def table(self, header, rows, caption="", cls="", **kw):
        self.items.append(("table", header, rows, caption))


def _ctx(pop, chain_s: float | None = None):
    page = Page()
    sections = []
    ev = SimpleNamespace(summary={"timings_s": {} if chain_s is None else {"chain_total": chain_s}})
    return SimpleNamespace(page=page, population=pop, ev=ev,
                           section=lambda title, anchor: sections.append(title)), sections


def _records():
    n = {"scans": 15, "targets": 250, "tracks": 990, "cells": 2970}
    over = ["scans", "targets", "tracks"]
    return [{"comparison": "with_uncertainty-model_based", "metric": "confident_error_final", "lo": -0.12,
             "hi": 0.02, "primary": True, "over": over, "n": n},
            {"comparison": "with_uncertainty-model_based", "metric": "correct_final", "lo": -0.03, "hi": 0.05,
             "primary": True, "over": over, "n": n}]


def test_the_power_section_states_the_widest_half_width_and_the_population_it_needs():
    power = power_block(_records(), available={"scans": 15})       # as evaluate writes it: no time
    ctx, sections = _ctx({"power": power}, chain_s=3600.0)
    power_section(ctx)
    assert sections == ["Power"]
    text = ctx.page.items[0][1]
    # half-width 0.07 over 15 scans: 15 * (0.07 / 0.05)^2 = 29.4 -> 30 scans, 500 targets, 2 h
    assert "1 of 2 primary comparisons" in text and "0.07" in text and "30 scans" in text
    assert "500 targets" in text and "2.0 h" in text and "30 scans needed, 15 exist" in text
    rows = ctx.page.items[1][2]
    assert rows[0][4] == "30 scans" and rows[1][4] == "reached"


def test_every_comparison_reached_is_said_so():
    recs = [dict(r, lo=-0.01, hi=0.02) for r in _records()]
    assert power_sentence(power_block(recs)).startswith("Every primary comparison")


def test_the_paper_setting_table_sits_beside_the_papers_figure_and_only_when_run():
    label = "sigma=0.3 m, bias=(-0.3, +0.2) m"
    est = lambda v: {"value": v, "ci_low": v - 0.05, "ci_high": v + 0.05}
    pop = {"methods": ["with_uncertainty", "model_based"], "scope": "15 scans, 250 targets x 990 tracks x 3 settings",
           "confident_threshold": 0.99,
           "settings": [{"experiment": "biased", "setting": "b", "sigma_m": 0.3, "bias_m": [-0.3, 0.2],
                         "realizations": 1},
                        {"experiment": "biased_randomized", "setting": label, "sigma_m": 0.3, "bias_m": [-0.3, 0.2],
                         "realizations": 20}],
           "by_setting": {label: {"pooled": {m: {"correct_final": est(0.7), "confident_error_final": est(v),
                                                 "log10_mgr95_final": est(1.0)}
                                             for m, v in (("with_uncertainty", 0.1), ("model_based", 0.25))}}}}
    ctx, sections = _ctx(pop)
    paper_setting(ctx, pop)
    assert sections == ["The paper's §5.5 setting"]
    _, header, rows, caption = ctx.page.items[0]
    assert [r[0].split(" (")[0] for r in rows] == ["With Uncertainty", "Model Based"]
    assert rows[1][2].value == 0.25 and "around 10 % of runs" in caption and "over scans, targets and tracks" in caption
    assert "N(0, 0.3 m) per axis" in caption and "told σ = 0.3 m" in caption
    pop["settings"] = pop["settings"][:1]
    ctx, sections = _ctx(pop)
    paper_setting(ctx, pop)
    assert sections == [] and ctx.page.items == []


def test_targets_as_the_unit_are_named_once():
    recs = [dict(r, over=["targets", "tracks"], n={"targets": 12, "tracks": 35}) for r in _records()]
    text = power_sentence(power_block(recs, seconds=600.0))
    assert "about 24 targets (20 min" in text and "24 targets, " not in text   # 12 x (0.07 / 0.05)^2 = 23.5


def test_the_summary_block_holds_no_measured_time_and_the_report_prices_it():
    recs = [dict(r, over=["targets", "tracks"], n={"targets": 12, "tracks": 35}) for r in _records()]
    block = power_block(recs)
    assert block["seconds_measured"] is None and all(e["cost_s"] is None for e in block["comparisons"])
    assert priced(block, 600.0) == power_block(recs, seconds=600.0)
    assert priced(block, None) is block


def test_a_crossed_design_projects_over_targets_and_scans_together():
    # half-width 0.1 over 20 targets crossed with 6 scans: x4 both -> 80 targets x 24 scans
    n = {"targets": 20, "scans": 6, "tracks": 40, "cells": 120}
    rec = {"comparison": "with_uncertainty-model_based", "metric": "correct_final", "lo": -0.05, "hi": 0.15,
           "primary": True, "over": ["targets", "scans"], "n": n, "cluster": "crossed"}
    block = power_block([rec], seconds=600.0, available={"scans": 15})
    (e,) = block["comparisons"]
    assert e["unit"] == "targets" and e["needed_units"] == 80 and e["needed_scans"] == 24 and e["scale"] == 4.0
    assert e["beyond"] == "24 scans needed, 15 exist" and "crossed" in block["assumption"]
    assert "caution" not in e
    few = power_block([dict(rec, n={**n, "scans": 3})])["comparisons"][0]
    assert few["caution"].startswith("3 scans:")                  # the smaller top level is the coarse one
    ctx, _ = _ctx({"power": block, "cluster": "crossed"}, chain_s=600.0)
    power_section(ctx)
    text, rows, caption = ctx.page.items[0][1], ctx.page.items[1][2], ctx.page.items[1][3]
    assert "over 20 targets crossed with 6 scans" in text and "about 80 targets crossed with 24 scans" in text
    assert rows[0][3] == "20 targets × 6 scans" and rows[0][4] == "80 targets × 24 scans"
    assert "cluster = 'crossed'" in caption and "targets and scans, crossed" in caption
    # a nested clustering projects over its own top level, named in the caption
    cat = dict(rec, over=["categories", "targets", "tracks"], n={"categories": 8, "targets": 72, "tracks": 144},
               cluster="category")
    ctx, _ = _ctx({"power": power_block([cat]), "cluster": "category"})
    power_section(ctx)
    assert ctx.page.items[1][2][0][3] == "8 categories" and "categories, targets and tracks" in ctx.page.items[1][3]
