"""Figure text that cannot collide (reports/shared/layout.py): the forest plot whose symlog axis
spans −1e4..1e4 (its decade labels touched and the strict report stopped a whole run) renders
clean once finished; thinning keeps the ticks and labels every n-th, anchored at 0; category
names keep every label; a long title is wrapped, never cut."""
from __future__ import annotations

from pipeline.evaluation.metrics.labels import comparison_key, comparisons
from reports.main.figures_results import fig_forest
from reports.shared.checks import figure_text_problems
from reports.shared.figures import new_figure, new_subplots, save
from reports.shared.layout import ThinnedFormatter, finish_figure


def _est(v, lo, hi):
    return {"value": v, "ci_low": lo, "ci_high": hi}


def _symlog_pop(n_targets: int = 3) -> dict:
    """Every log10 MGR difference spans −1e4..1e4: eleven decade ticks on a third of the width."""
    keys = [comparison_key(*c) for c in comparisons()]
    targets = [f"target_{i}" for i in range(n_targets)]
    row = {"correct_final": _est(0.1, -0.1, 0.3), "prob_truth_final": _est(0.1, 0.0, 0.2),
           "log10_mgr95_final": _est(-5e3, -1e4, 1e4)}
    return {"targets": targets, "paired_per_target": {k: {t: dict(row) for t in targets} for k in keys},
            "paired": {k: dict(row) for k in keys},
            "tracks": [{"target": t} for t in targets for _ in range(3)]}


def test_the_forest_plot_over_minus_1e4_to_1e4_touched_before_finishing():
    fig = fig_forest(_symlog_pop())
    problems = figure_text_problems(fig, "forest.png")
    # the failure the finishing step exists for: neighbouring decade labels run together
    assert problems and all("overlaps" in p and "1e" in p for p in problems), problems


def test_the_forest_plot_over_minus_1e4_to_1e4_renders_clean(tmp_path):
    fig = fig_forest(_symlog_pop())
    save(fig, tmp_path / "forest.png")          # the report's save path finishes every figure
    assert figure_text_problems(fig, "forest.png") == []
    mgr_ax = fig.axes[2]
    labels = [t.get_text() for t in mgr_ax.get_xticklabels() if t.get_text().strip()]
    assert "0" in labels and len(labels) >= 3, labels   # thinned, not emptied; 0 stays


def test_thinning_keeps_the_ticks_and_labels_every_nth_from_zero():
    fig, ax = new_figure(2.0, 2.0)
    ax.plot(range(-50, 51), range(-50, 51))
    ax.set_xticks(range(-50, 51, 5))
    n_ticks = len(ax.get_xticks())
    finish_figure(fig)
    assert len(ax.get_xticks()) == n_ticks
    assert isinstance(ax.xaxis.get_major_formatter(), ThinnedFormatter)
    shown = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert "0" in shown and 2 <= len(shown) < n_ticks
    assert figure_text_problems(fig) == []


def test_category_names_keep_every_label():
    fig, ax = new_figure(4.0, 1.5)
    names = [f"a long object name number {i}\n(3 tracks)" for i in range(12)]
    ax.set_yticks(range(12))
    ax.set_yticklabels(names)
    ax.plot([0, 1], [0, 11])
    assert figure_text_problems(fig)
    finish_figure(fig)
    assert figure_text_problems(fig) == []
    assert [t.get_text() for t in ax.get_yticklabels()] == names


def test_a_title_longer_than_the_canvas_is_wrapped_not_cut():
    fig, axes = new_subplots(1, 3, w=6.0, h=3.0)
    long = "a_very_long_object_name_without_spaces_that_runs_on " * 2
    for ax in axes[0]:
        ax.set_title(long)
    finish_figure(fig)
    assert figure_text_problems(fig) == []
    for ax in axes[0]:
        assert ax.get_title().replace("\n", "").replace(" ", "") == long.replace(" ", "")


def _axes_positions(fig):
    return [tuple(ax.get_position().bounds) for ax in fig.axes]


def test_save_freezes_the_layout_it_checked_and_its_check_is_the_checkers(tmp_path):
    import numpy as np

    fig = fig_forest(_symlog_pop(5))
    chk = save(fig, tmp_path / "forest.png")
    assert fig.get_layout_engine() is None or fig.get_layout_engine().__class__.__name__ == "PlaceHolderLayoutEngine"
    frozen = _axes_positions(fig)
    # the frozen places are the layout's own: solving it again on the finished figure moves nothing
    # (within 1e-4 of the canvas, a tenth of a pixel: the solver is not exactly idempotent)
    fig.set_layout_engine("constrained")
    fig.draw_without_rendering()
    np.testing.assert_allclose(_axes_positions(fig), frozen, atol=1e-4)
    # and save's one-placement check says what the checker says after a fresh draw
    assert list(chk.text_problems) == figure_text_problems(fig, "forest.png") == []


def test_save_checks_a_figure_that_was_never_finished(tmp_path, monkeypatch):
    from reports.shared import layout

    monkeypatch.setattr(layout, "finish_figure", lambda fig: [])   # nothing draws or fixes it
    chk = save(fig_forest(_symlog_pop()), tmp_path / "forest.png")
    assert chk.text_problems and all("overlaps" in p for p in chk.text_problems), chk.text_problems
    assert chk.overlaps                     # the decade labels that touch, seen by the tick check too
