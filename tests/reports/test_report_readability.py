"""What makes the report readable in five minutes: the computed bottom line, honest counts, the
showcase rule, symlog MGR axes without overlapping ticks, legible text, alt text with findings."""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.grid import showcase
from reports.main.bottom_line import bottom_line, counts, no_ci_reason
from reports.main.figures_results import constant_note, fig_forest
from reports.shared.figures import check, mgr_axis, new_figure, tick_overlaps
from tests.support.report_fixtures import rendered_run, rendered_run_default_dpi  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

WU_MB, WU_SB = "with_uncertainty-model_based", "with_uncertainty-simple_bayes"


def _pop() -> dict:
    rows = [(WU_MB, "correct_final", "not distinguishable"), (WU_MB, "log10_mgr75_final", "better"),
            (WU_MB, "log10_mgr95_final", "better"), (WU_SB, "correct_final", "worse"),
            (WU_SB, "log10_mgr75_final", "better"), (WU_SB, "log10_mgr95_final", "not distinguishable")]
    tracks = [{"target": "a", "track": i} for i in range(8)] + [{"target": "b", "track": 0}] \
        + [{"target": "c", "track": i} for i in range(4)]
    return {"n_targets": 3, "n_tracks": 13, "n_cells": 39, "targets": ["a", "b", "c"], "tracks": tracks,
            "settings": [{"setting": "biased", "realizations": 1}, {"setting": "s=0.1", "realizations": 20},
                         {"setting": "s=0.3", "realizations": 20}],
            "verdict_table": [{"comparison": c, "metric": m, "outcome": o} for c, m, o in rows]}


def test_counts_give_tracks_per_target_min_max_cells_and_realizations_per_setting():
    c = counts(_pop())
    assert (c["tracks_min"], c["tracks_max"], c["n_cells"], c["n_settings"]) == (1, 8, 39, 3)
    assert c["single_track_targets"] == ["b"] and c["single_realization_settings"] == ["biased"]
    assert no_ci_reason({"value": 0.5, "ci_low": float("nan"), "ci_high": float("nan")}, 1).startswith("1 track")
    assert no_ci_reason({"value": 0.5, "ci_low": 0.4, "ci_high": 0.6}, 3) == ""


def test_bottom_line_is_computed_from_the_verdict_table_and_names_the_scope():
    first, second = bottom_line(_pop(), {"weights": "synthetic"})
    assert first.startswith("Bottom line. With Uncertainty vs Model Based: better on log10 MGR; not distinguishable "
                            "on correct ratio.")
    # a family with mixed outcomes is spelled out entry by entry
    assert "With Uncertainty vs Simple Bayes: better on log10 MGR 75th percentile, final step" in first
    assert "worse on correct ratio" in first
    assert "over 3 targets and 13 tracks, 1–8 per target" in second and "one classifier training run" in second
    from reports.main.bottom_line import scope_text
    scope = scope_text(counts(_pop()))
    assert "3 targets, 13 tracks, 1–8 per target, 3 localization settings: 39 (target, track, setting) cells" in scope
    assert "realizations per cell: 1 (biased), 20 (s=0.1), 20 (s=0.3)" in scope
    flipped = _pop()
    flipped["verdict_table"][0]["outcome"] = "worse"
    assert bottom_line(flipped)[0] != first          # the sentence follows the table, it is not fixed text


def test_bottom_line_speaks_of_the_primary_metrics_only():
    pop = _pop()
    pop["records"] = [{**r, "primary": r["metric"] == "correct_final"} for r in pop.pop("verdict_table")]
    first = bottom_line(pop)[0]
    assert first.startswith("Bottom line (primary metrics: correct ratio, final step; every other metric is "
                            "exploratory).")
    assert "With Uncertainty is not distinguishable from Model Based on any metric" in first
    assert "worse on correct ratio" in first and "log10 MGR" not in first.split(").", 1)[1]


def test_the_showcase_is_the_track_where_the_methods_disagree_most():
    rows = []
    spread = {("a", 0): (0.0, 0.0), ("a", 1): (0.5, 0.5), ("b", 0): (0.5, 0.9), ("b", 1): (0.1, 0.1)}
    for (t, k), (lo, hi) in spread.items():
        for s in ("biased", "random"):
            for m, v in (("wu", hi), ("mb", lo), ("sb", lo)):
                rows.append({"variant": "default", "target": t, "track": k, "setting": s, "method": m,
                             "correct_final": v, "prob_truth_final": v / 2})
    rows.append({"variant": "abl", "target": "a", "track": 0, "setting": "biased", "method": "wu",
                 "correct_final": 1.0, "prob_truth_final": 1.0})
    got = showcase.choose(pd.DataFrame(rows))
    assert (got["target"], got["track"]) == ("b", 0) and got["correct_spread"] == pytest.approx(0.4)
    assert got["rule"] == showcase.RULE and got["candidates"] == 4 and got["ties"] == 0


def test_symlog_mgr_axis_keeps_far_apart_values_readable_and_ticks_apart():
    fig, ax = new_figure(3.4, 3.0)
    vals = [-4e5, -3e5, -120.0, -0.2, 0.0, 0.4, 35.0]
    ax.plot(vals, range(len(vals)), "o")
    mgr_axis(ax, vals, axis="x")
    assert ax.get_xscale() == "symlog" and tick_overlaps(fig) == []
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert "0" in labels and any("1e" in x for x in labels)


def test_tick_overlap_check_catches_labels_that_run_together():
    fig, ax = new_figure(2.0, 2.0)
    ax.set_xticks(np.arange(12) * 1e5)
    ax.set_xticklabels([f"{-400000 + i * 100000}" for i in range(12)])
    assert tick_overlaps(fig)


def test_forest_with_huge_mgr_differences_has_no_overlapping_ticks_and_legible_text():
    targets = [f"target_{i}" for i in range(6)]
    e = lambda v: {"value": v, "ci_low": v - abs(v) / 4 - 0.1, "ci_high": v + abs(v) / 4 + 0.1}
    ppt = {WU_MB: {t: {"correct_final": e(0.1 * i), "prob_truth_final": e(0.05), "log10_mgr95_final": e(-(10 ** i))}
                   for i, t in enumerate(targets)}}
    pop = {"targets": targets, "paired_per_target": ppt,
           "paired": {WU_MB: {"correct_final": e(0.1), "prob_truth_final": e(0.0), "log10_mgr95_final": e(-4e5)}}}
    fig = fig_forest(pop)
    chk = check(fig, 110)
    assert chk.overlaps == () and chk.min_font_px >= 11 and chk.width_px <= 1210


def test_a_band_without_spread_is_annotated():
    assert "does not reach this method" in constant_note(np.full((5, 4), 0.2))
    assert constant_note(np.random.default_rng(0).random((5, 4))) == ""


def test_alt_text_states_findings_and_headers_have_scope(rendered_run):  # noqa: F811
    _, res = rendered_run
    text = res.index.read_text()
    figs = re.findall(r'<img src="([^"]+)" alt="([^"]*)"[^>]*>\s*<figcaption>([^<]*)</figcaption>', text)
    assert len(figs) == len(res.figures)
    for name, alt, cap in figs:
        assert alt and alt != cap, name
        assert re.search(r"\d", alt), f"{name}: alt text without a number: {alt}"
    assert '<th scope="col">' in text and '<th scope="row">' in text and "<th>" not in text
    assert 'id="glossary"' in text and "<dt>MSDE</dt>" in text and "<dt>cell</dt>" in text
    assert 'class="bottomline">Bottom line (primary metrics: correct ratio, final step;' in text


def test_every_report_figure_at_the_default_dpi_is_legible(rendered_run_default_dpi):  # noqa: F811
    _, res = rendered_run_default_dpi
    text = res.index.read_text()
    sizes = {n: float(px) for n, px in re.findall(r'<img src="([^"]+)"[^>]*data-min-font-px="([\d.]+)"', text)}
    assert set(sizes) == set(res.figures)
    assert min(sizes.values()) >= 11, sizes
    assert not [n for n in res.notes if "tick labels overlap" in n]
    assert set(re.findall(r'data-tick-overlaps="(\d+)"', text)) == {"0"}


def test_sentences_from_summary_json_use_the_one_number_format():
    from reports.shared.numbers import reformat_numbers
    s = ("better (difference -1.41, 95 % CI [-2.34, -0.7], over 12 targets x 83 tracks; better in 92% of cells); "
         "7.62e-19 [4.09e-20, 2.14e-18], +0.217")
    assert reformat_numbers(s) == ("better (difference −1.41, 95 % CI [−2.34, −0.700], over 12 targets x 83 tracks; "
                                   "better in 92 % of cells); < 1e-6 [< 1e-6, < 1e-6], +0.217")
