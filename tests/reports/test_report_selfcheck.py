"""The report build fails on what its self-checks catch (reports/shared/checks.py), planted into a
real build of a fake run: a verdict label its CI contradicts, a figure title printed over another,
a clipped y label, a caption that states no finding; a clean build passes, and so does the real
default run where one exists. The page's words are plain: no internal names, one percent style,
one minus sign, and every technical term it uses is in its glossary."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from reports.main import findings, scorecard
from reports.main import page as page_module
from reports.main.page import build_main_report
from reports.shared.checks import ReportCheckError, page_text, plain_words_problems
from reports.shared.figures import new_figure
from tests.support.report_fixtures import only_figures, rendered_run, write_fake_run  # noqa: F401 (fixture)

pytestmark = pytest.mark.slow  # renders whole reports (make test-fast skips it)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def fake_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("selfcheck")
    write_fake_run(root / "run", K=4, R=4)
    return root / "run"


def _build(run, out):
    return build_main_report(run, out, dpi=60, progress=False, n_boot=100)


def test_a_clean_build_passes_and_writes_the_page(fake_run, tmp_path):
    res = _build(fake_run, tmp_path / "out")
    assert res.index.exists() and "reproduce" in res.sections and "scorecard" in res.index.read_text()


def test_a_planted_label_that_its_ci_contradicts_fails_the_build(fake_run, tmp_path, monkeypatch):
    # every claim of the scorecard labelled 'fails', whatever its interval says
    only_figures(monkeypatch)   # the scorecard is a table: no figure needed
    monkeypatch.setattr(scorecard, "claim_status", lambda entry, metric: "fails")
    with pytest.raises(ReportCheckError, match=r"claims scorecard\): labelled 'fails' but its interval"):
        _build(fake_run, tmp_path / "out")
    assert not (tmp_path / "out" / "index.html").exists()   # nothing contradictory is published


def test_a_planted_mismatch_in_an_ablation_row_fails_the_build(fake_run, tmp_path, monkeypatch):
    # the ablation table shows a difference its verdict record does not hold
    from reports.main import verdict

    only_figures(monkeypatch)
    real = verdict.paired_value

    def shifted(block, comparison, metric):
        d = real(block, comparison, metric)
        return {**d, "value": d["value"] + 0.05} if d and "override" in block and metric == "correct_final" else d

    monkeypatch.setattr(verdict, "paired_value", shifted)
    with pytest.raises(ReportCheckError, match=r"ablation / models.noise_floor=dropout / .* / correct_final: its "
                                               r"verdict record .* but ablation table shows"):
        _build(fake_run, tmp_path / "out")
    assert not (tmp_path / "out" / "index.html").exists()


def _overlapping_titles(pop):
    fig, ax = new_figure(4.0, 3.0)
    ax.set_title("a title placed by hand")
    fig.text(0.5, 0.5, "a text over the title", transform=ax.title.get_transform(), ha="center", fontsize=12)
    fig.canvas.draw()
    fig.texts[0].set_position(ax.title.get_position())
    fig.set_layout_engine("none")
    return fig


def _clipped_ylabel(pop):
    fig, ax = new_figure(4.0, 1.6)
    ax.plot([0, 1], [0, 1])
    ax.set_ylabel("a y label far taller than the axes it labels, so both ends leave the canvas")
    return fig


def _slip_past_layout(monkeypatch, planted):
    """A figure whose text problem the finishing step does not fix (it is switched off)."""
    from reports.shared import layout
    monkeypatch.setattr(page_module, "fig_forest", planted)
    monkeypatch.setattr(layout, "finish_figure", lambda fig: [])
    only_figures(monkeypatch, "forest.png")


@pytest.mark.parametrize("planted, message", [(_overlapping_titles, "overlaps"), (_clipped_ylabel, "is clipped")])
def test_planted_figure_text_problems_fail_the_build_under_strict_all(fake_run, tmp_path, monkeypatch, planted,
                                                                      message):
    _slip_past_layout(monkeypatch, planted)
    with pytest.raises(ReportCheckError, match=f"forest.png: text .* {message}"):
        _build(fake_run, tmp_path / "out")


def test_the_finishing_step_fixes_a_clipped_label_before_the_check(fake_run, tmp_path, monkeypatch):
    monkeypatch.setattr(page_module, "fig_forest", _clipped_ylabel)
    only_figures(monkeypatch, "forest.png")
    res = _build(fake_run, tmp_path / "out")
    assert res.layout_problems == {}


def test_a_layout_slip_under_strict_contradictions_is_written_with_a_warning_box(fake_run, tmp_path, monkeypatch,
                                                                                caplog):
    _slip_past_layout(monkeypatch, _overlapping_titles)
    with caplog.at_level("WARNING", logger="viewfuse.report"):
        res = build_main_report(fake_run, tmp_path / "out", dpi=60, progress=False, n_boot=100,
                                strict="contradictions")
    html = res.index.read_text()
    assert list(res.layout_problems) == ["forest.png"]
    box = html.index("figure-warning")
    figure = html[html.rindex("<figure>", 0, box):html.index("</figure>", box)]
    assert 'src="forest.png"' in figure and "Layout check" in figure and "overlaps" in figure
    assert html.count("figure-warning") == 1
    assert any("forest.png" in r.getMessage() for r in caplog.records if r.levelname == "WARNING")


def test_a_contradiction_under_strict_contradictions_still_fails(fake_run, tmp_path, monkeypatch):
    only_figures(monkeypatch)
    monkeypatch.setattr(scorecard, "claim_status", lambda entry, metric: "fails")
    with pytest.raises(ReportCheckError, match="labelled 'fails'"):
        build_main_report(fake_run, tmp_path / "out", dpi=60, progress=False, n_boot=100, strict="contradictions")
    assert not (tmp_path / "out" / "index.html").exists()


def test_a_caption_without_a_finding_is_fatal_under_strict_contradictions(fake_run, tmp_path, monkeypatch):
    only_figures(monkeypatch, "per_target.png")
    monkeypatch.setattr(findings, "per_target", lambda pop, ledger=None: "")
    with pytest.raises(ReportCheckError, match="caption states no finding"):
        build_main_report(fake_run, tmp_path / "out", dpi=60, progress=False, n_boot=100, strict="contradictions")


def test_a_caption_without_a_finding_fails_the_build(fake_run, tmp_path, monkeypatch):
    only_figures(monkeypatch, "per_target.png")
    monkeypatch.setattr(findings, "per_target", lambda pop, ledger=None: "")
    with pytest.raises(ReportCheckError, match="per_target.png: caption states no finding"):
        _build(fake_run, tmp_path / "out")


# Technical terms a reader may meet on the page, each of which the glossary must define.
TERMS = ("P(truth)", "correct ratio", "log10 MGR", "MSDE", "NLL", "ECE", "PIT", "confident-error rate",
         "calibrated likelihood", "paired difference", "realization", "cell", "setting", "95 % CI", "ablation",
         "holds / fails / inconclusive", "score component", "showcase track", "numerical saturation",
         "supported / not supported in this setting")


def test_the_page_speaks_plain_words_and_its_glossary_defines_its_terms(rendered_run):  # noqa: F811
    _, res = rendered_run
    html = res.index.read_text()
    assert plain_words_problems(html) == []
    glossary = html[html.index('<dl class="glossary">'):html.index("</dl>", html.index('<dl class="glossary">'))]
    body = " ".join(page_text(html.replace(glossary, "")))
    dts = [t.split("</dt>")[0] for t in glossary.split("<dt>")[1:]]
    missing = [t for t in TERMS if t.split(" / ")[0] in body and not any(t.split(" / ")[0] in d for d in dts)]
    assert missing == [], f"terms on the page but not in its glossary: {missing}"


def test_the_plain_words_walk_catches_internal_names_and_mixed_styles():
    bad = ("<p>WU beats N_x samples; see `cross_fit` and population.showcase (issue 20); 1 target(s); "
           "8% of cells; bias (-0.30, +0.20) m</p><pre>N_x = 3 in a config dump is fine</pre>")
    found = " | ".join(plain_words_problems(bad))
    for name in ("'WU'", "'N_x'", "'cross_fit'", "'population.showcase'", "'issue 20'", "'`'", "t(s)",
                 "without a space", "hyphen as minus"):
        assert name in found, name
    assert "config dump" not in found


def _default_run() -> Path:
    return Path(os.environ.get("VIEWFUSE_RUN") or ROOT / "artifacts" / "synthetic")


def test_the_real_default_run_builds_without_a_self_check_failure(tmp_path):
    run = _default_run()
    summary = run / "evaluate" / "summary.json"
    if not summary.exists():
        pytest.skip(f"no finished default run at {run} (make evaluate, or set VIEWFUSE_RUN to a run folder)")
    pop = json.loads(summary.read_text()).get("population") or {}
    if "records" not in pop:
        pytest.skip(f"{summary} predates the verdict records: its labels and numbers come from different "
                    "statistics (rerun the evaluate stage)")
    res = build_main_report(run, tmp_path / "out", progress=False)
    assert plain_words_problems(res.index.read_text()) == []
