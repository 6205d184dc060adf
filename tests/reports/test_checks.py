"""The report's build-time self-checks (reports/shared/checks.py) catch what they promise: planted
overlapping titles, clipped labels, label/CI contradictions, two numbers for one statistic and
captions without a finding; clean figures and consistent numbers pass."""
from __future__ import annotations

import pytest

from reports.shared.checks import (
    Ledger,
    ReportCheckError,
    caption_problem,
    figure_text_problems,
    outcome_of,
)
from reports.shared.figures import new_figure, new_subplots


def test_a_clean_figure_has_no_text_problems():
    fig, ax = new_figure(6.4, 4.0)
    ax.plot([0, 1, 2], [0, 1, 4], label="a line")
    ax.set_title("a title")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend()
    assert figure_text_problems(fig, "clean") == []


def test_panel_titles_printed_over_each_other_are_caught():
    fig, axes = new_subplots(1, 4, w=6.0, h=3.0)
    for ax in axes[0]:
        ax.set_title("With Uncertainty, a long panel title\nR = 30 realizations")
    problems = figure_text_problems(fig, "planted")
    assert any("overlaps" in p and "With Uncertainty" in p for p in problems), problems


def test_a_suptitle_over_an_axes_title_is_caught():
    fig, ax = new_figure(5.0, 3.0)
    ax.set_title("panel title")
    fig.text(0.5, 0.93, "a figure title placed by hand", ha="center", fontsize=14)
    fig.canvas.draw()
    fig.set_layout_engine("none")
    t = fig.texts[0]
    t.set_position(ax.title.get_position())
    t.set_transform(ax.transAxes)
    t.set_va("baseline")
    assert any("overlaps" in p for p in figure_text_problems(fig, "planted"))


def test_a_y_label_taller_than_the_figure_is_caught_as_clipped():
    fig, ax = new_figure(5.0, 2.0)
    ax.plot([0, 1], [0, 1])
    ax.set_ylabel("a y label\nthat runs much longer than the axes are tall, so its ends leave the canvas")
    problems = figure_text_problems(fig, "planted")
    assert any("clipped" in p and "y label" in p for p in problems), problems


def test_neighbouring_tick_labels_that_run_together_are_caught():
    fig, ax = new_figure(3.0, 2.5)
    ax.set_xticks(range(8))
    ax.set_xticklabels([f"long tick label {i}" for i in range(8)])
    assert any("long tick label" in p for p in figure_text_problems(fig, "planted"))


def test_a_label_that_its_interval_contradicts_fails():
    led = Ledger()
    led.register(("paired", "wu−mb", "log10_mgr95_final"), -30700, -97500, -32.5, label="not distinguishable",
                 where="paired table", higher_is_better=False)
    led.register(("paired", "wu−sb", "correct_final"), 0.02, -0.01, 0.05, label="better", where="bottom line",
                 higher_is_better=True)
    led.register(("paired", "wu−sb", "msde_final"), -0.02, -0.03, -0.01, label="worse", where="forest",
                 higher_is_better=False)
    problems = led.problems()
    assert len(problems) == 3, problems
    assert "excludes 0" in problems[0] and "contains 0" in problems[1] and "good side" in problems[2]
    with pytest.raises(ReportCheckError, match="3 problems"):
        raise ReportCheckError(problems)


def test_two_numbers_for_one_statistic_fail_and_one_number_shown_twice_passes():
    led = Ledger()
    led.register(("pooled", "wu", "log10_mgr95_final"), 12.1, 8.0, 15.0, where="headline table")
    led.register(("pooled", "wu", "log10_mgr95_final"), 12.1, 8.0, 15.0, where="per-target figure")
    assert led.problems() == []
    led.register(("pooled", "wu", "log10_mgr95_final"), 1830, 900, 2900, where="all-metrics table")
    (p,) = led.problems()
    assert "headline table" in p and "all-metrics table" in p


def test_a_value_outside_its_interval_and_a_label_without_interval_fail():
    led = Ledger()
    led.register("x", 5.0, 0.0, 1.0)
    led.register("y", 1.0, None, None, label="holds")
    assert len(led.problems()) == 2


def test_consistent_labels_pass_and_follow_the_one_outcome_rule():
    led = Ledger()
    for lo, hi, higher in ((0.01, 0.3, True), (-0.3, -0.01, True), (-0.1, 0.2, True), (-0.3, -0.01, False)):
        led.register(("k", lo, hi, higher), (lo + hi) / 2, lo, hi, label=outcome_of(lo, hi, higher),
                     higher_is_better=higher)
    assert led.problems() == []
    assert outcome_of(-0.3, -0.01, False) == "better" and outcome_of(-0.1, 0.2, True) == "not distinguishable"


@pytest.mark.parametrize("caption", [
    "Paired differences per target and pooled, with 95 % bootstrap CIs over tracks.",
    "Each method per target and pooled, 95 % CIs.",
    "With Uncertainty is better than Simple Bayes.",
])
def test_a_caption_without_a_finding_fails(caption):
    assert caption_problem("fig.png", caption)


def test_a_caption_with_a_number_and_a_comparison_passes():
    assert caption_problem("fig.png", "With Uncertainty wins 7 of 12 targets; pooled +0.18 [+0.01, +0.32], "
                                      "better than Simple Bayes.") == ""


def test_a_log_axis_with_the_default_formatter_prints_markup_and_is_caught():
    fig, ax = new_figure(4.0, 3.0)
    ax.bar([0, 1], [1, 1000])
    ax.set_yscale("log")              # '$\\mathdefault{10^{3}}$' with mathtext off
    assert any("mathtext markup" in p for p in figure_text_problems(fig, "planted"))
