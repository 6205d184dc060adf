"""Report: number format, HTML builder, figure helpers, CIs over realizations, and the main report
rendered from a fake run folder that follows the evaluate → report contract."""
from __future__ import annotations

import io
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from loaders.errors import BadInputError
from pipeline.evaluation.metrics import labels
from reports.main.figures_models import bias_map_rgb
from reports.main.page import build_main_report
from reports.shared.figures import new_figure, percentile_bands, save
from reports.shared.html import HtmlReport
from reports.shared.numbers import Estimate, fmt
from reports.shared.records import sentence
from reports.shared.stats import bootstrap_track
from reports.shared.tables import dump_toml, hyperparameter_table
from tests.support.params import PARAMS
from tests.support.report_fixtures import CLASSES, rendered_run, write_fake_run  # noqa: F401 (fixture)

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NUM = r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


class _Page(HTMLParser):
    """Collects images, tables (class, section, cells), section ids in order, list items, details."""

    def __init__(self):
        super().__init__()
        self.imgs, self.tables, self.sections, self.ids, self.links = [], [], [], [], []
        self.verdict, self.details, self.scripts = [], 0, 0
        self._cell = self._li = None
        self._in_details = 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a.get("src"))
        elif tag == "section":
            self.sections.append(a.get("id"))
        elif tag == "table":
            self.tables.append({"cls": a.get("class", ""), "section": self.sections[-1] if self.sections else None,
                                "collapsed": self._in_details > 0, "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "li":
            self._li = []
        elif tag == "details":
            self.details += 1
            self._in_details += 1
        elif tag == "script":
            self.scripts += 1
        elif tag in ("link", "a"):
            self.links.append(a.get("href", ""))
        if "id" in a:
            self.ids.append(a["id"])

    def handle_data(self, data):
        for buf in (self._cell, self._li):
            if buf is not None:
                buf.append(data)

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1]["rows"][-1].append("".join(self._cell))
            self._cell = None
        elif tag == "li" and self._li is not None:
            self.verdict.append("".join(self._li))
            self._li = None
        elif tag == "details":
            self._in_details -= 1

    def table(self, cls: str) -> dict:
        found = [t for t in self.tables if cls in t["cls"].split()]
        assert len(found) == 1, (cls, [t["cls"] for t in self.tables])
        return found[0]


def parse(path) -> _Page:
    p = _Page()
    p.feed(Path(path).read_text())
    return p


def estimate(cell: str) -> tuple[float, float, float]:
    v, lo, hi = (float(x) for x in re.findall(NUM, cell)[:3])
    return v, lo, hi


def shown_tol(cell: str) -> float:
    """Half the last digit of a cell's value: values are shown to the place their CI's width allows
    (reports.shared.numbers.ci_digits), so a check against the exact value allows that much."""
    tok = re.findall(NUM, cell)[0]
    return max(6e-3, (10.0 ** -len(tok.split(".")[1]) if "." in tok else 1.0) / 2 + 1e-12)


# -- numbers and labels -------------------------------------------------------------------------
def test_one_number_format_with_significant_digits():
    assert [fmt(x) for x in (1, 0.8856, 0.1958, 77.8, 0.0)] == ["1.00", "0.886", "0.196", "77.8", "0.00"]
    # plain decimals down to 1e-6 (no mixed formats in one column), a short exponent from 1e5
    assert fmt(3.295e-4) == "0.000329" and fmt(-7.93e-4) == "−0.000793" and fmt(123456.0) == "1.23e5"
    # below 1e-6 the digits are noise: "< 1e-6", never "7.62e-19"
    assert fmt(7.62e-19) == "< 1e-6" and fmt(-2e-9) == "> −1e-6" and fmt(9.996) == "10.0"
    assert fmt(9.5e-6) == "9.50e-6" and fmt(1836.2) == "1840"
    assert Estimate(7.62e-19, 4.09e-20, 2.14e-18).text() == "< 1e-6 [< 1e-6, < 1e-6]"
    assert Estimate(0.5, float("nan"), float("nan")).text() == "0.500"  # no interval: the value alone
    assert fmt(None) == fmt(float("nan")) == "—" and fmt(float("inf")) == "∞"
    # digits follow the CI's width (two significant digits of it); an end that would round to 0 keeps its own
    assert Estimate(0.46, 0.31, 0.6).text() == "0.46 [0.31, 0.60]"
    assert Estimate(0.181, 0.0139, 0.319, signed=True).text() == "+0.18 [+0.01, +0.32]"
    assert Estimate(0.003, 0.001, 0.9).text() == "0.0030 [0.0010, 0.90]"
    assert Estimate(0.46, 0.31, 0.6).text(sig=3) == "0.460 [0.310, 0.600]"
    assert Estimate(0.5).text() == "0.500"
    assert Estimate.of({"value": 1, "ci_low": -1, "ci_high": 2}).excludes_zero() is False
    assert Estimate.of({"value": 1, "ci_low": 0.5, "ci_high": 2}).excludes_zero() is True


def test_labels_are_the_one_place_and_class_colours_never_use_a_method_hue():
    import reports.shared.figures as F
    assert not hasattr(F, "METHOD_STYLE")
    assert labels.method_label("with_uncertainty") == "With Uncertainty (Feldman & Indelman)"
    assert labels.method_label("model_based") == "Model Based (Teacy et al.)"
    assert not set(labels.class_colors(12)) & {labels.method_color(m) for m in labels.methods()}
    assert labels.ordered_methods({"simple_bayes", "zzz", "with_uncertainty"}) == ["with_uncertainty", "simple_bayes", "zzz"]
    assert labels.comparison_label("with_uncertainty-model_based") == "With Uncertainty − Model Based"


# -- HtmlReport ---------------------------------------------------------------------------------
def test_html_escapes_text_and_keeps_anchors_unique(tmp_path):
    r = HtmlReport("A <b> title", "sub & more", badge="synthetic data")
    r.section("Results")
    r.paragraph("x < y & <script>alert(1)</script>")
    r.section("Results")
    r.table(["a", "b"], [[1, 0.123456], [None, float("nan")], [float("inf"), True]], cls="summary")
    r.table(["a"], [[Estimate(1.0, 0.5, 2.0)]], collapsed="more")
    r.preformatted("<raw>")
    r.write(tmp_path / "index.html")
    text = (tmp_path / "index.html").read_text()
    page = parse(tmp_path / "index.html")
    assert "<script>" not in text and page.scripts == 0
    assert "A &lt;b&gt; title" in text and "&lt;raw&gt;" in text and 'class="tag">synthetic data' in text
    assert page.ids.count("results") == 1 and "results-2" in page.ids
    rows = page.tables[0]["rows"]
    assert rows[1] == ["1", "0.123"] and rows[2] == ["—", "—"] and rows[3] == ["∞", "yes"]
    assert page.tables[1]["collapsed"] and page.tables[1]["rows"][1] == ["1.0 [0.5, 2.0]"]  # digits follow the CI width
    assert [p.name for p in tmp_path.iterdir()] == ["index.html"]  # no temp file left behind


@pytest.mark.parametrize("ch", ["\u202e", "\u202d", "\u2066", "\u2069", "\u200f", "\u061c", "\x1b", "\x00", "\x85"])
def test_bidi_and_control_characters_in_labels_and_notes_are_shown_not_obeyed(tmp_path, ch):
    # a method note or label with a right-to-left override must not reorder the page around it
    r = HtmlReport(f"run{ch}name")
    r.section("Methods")
    r.table(["method", "what it does"], [[f"evil{ch}label", f"note {ch}txt.exe"]])
    r.paragraph(f"para{ch}graph")
    r.preformatted(f"pre{ch}formatted")
    r.write(tmp_path / "index.html")
    text = (tmp_path / "index.html").read_text()
    assert ch not in text
    assert f"evil[U+{ord(ch):04X}]label" in text and f"note [U+{ord(ch):04X}]txt.exe" in text
    assert f"pre[U+{ord(ch):04X}]formatted" in text


def test_html_rejects_bad_tables_and_non_relative_figures():
    r = HtmlReport("t")
    with pytest.raises(ValueError, match="row 0 has 1 cells"):
        r.table(["a", "b"], [[1]])
    for bad in ("http://example.com/a.png", "/abs/a.png", "../up.png", "data:image/png;base64,AA"):
        with pytest.raises(ValueError, match="relative"):
            r.figure(bad, "c")


# -- figure helpers -----------------------------------------------------------------------------
def test_percentile_bands_are_steps_at_the_numpy_percentiles():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(41, 5)).cumsum(axis=1)
    fig, ax = new_figure()
    percentile_bands(ax, np.arange(5), v, labels.method_color("model_based"), "MB")
    polys = ax.collections
    assert len(polys) == 4  # 10–90, 20–80, 30–70, 40–60
    verts = polys[0].get_paths()[0].vertices
    lo, hi = np.percentile(v, 10, axis=0), np.percentile(v, 90, axis=0)
    path = polys[0].get_paths()[0]
    for k in range(5):
        # A step band is flat across each step: exactly [lo, hi] from k - 0.4 to k + 0.4
        # (the first and last steps keep to the data's range).
        for x in (max(k - 0.4, 0.05), min(k + 0.01, 3.99), min(k + 0.4, 3.95)):
            assert path.contains_point((x, (lo[k] + hi[k]) / 2))
            assert not path.contains_point((x, hi[k] + 1e-3)) and not path.contains_point((x, lo[k] - 1e-3))
            assert path.contains_point((x, hi[k] - 1e-3)) and path.contains_point((x, lo[k] + 1e-3))
    assert set(np.round(verts[:, 0], 6)) == {0.0, 0.5, 1.5, 2.5, 3.5, 4.0}   # jumps halfway between steps
    med = ax.lines[-1]
    assert med.get_drawstyle() == "steps-mid"
    np.testing.assert_allclose(med.get_ydata(), np.median(v, axis=0))
    with pytest.raises(ValueError, match="K = 4"):
        percentile_bands(ax, np.arange(4), v, "k")


def test_save_writes_png_atomically(tmp_path):
    fig, ax = new_figure(2, 2)
    ax.plot([0, 1], [1, 0])
    save(fig, tmp_path / "a.png", dpi=40)
    save(fig, tmp_path / "a.png", dpi=40)
    assert (tmp_path / "a.png").read_bytes()[:8] == PNG_MAGIC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]
    with pytest.raises(ValueError, match=".png"):
        save(fig, tmp_path / "a.jpg", dpi=40)


def test_bias_map_rgb_hue_is_argmax_and_brightness_grows_with_probability():
    post = np.zeros((3, 1, 3))
    post[:, 0, 0] = 1 / 3                # uniform -> darkest
    post[:, 0, 1] = [0.2, 0.7, 0.1]      # class 1 wins, fairly sure
    post[:, 0, 2] = [0.0, 0.0, 1.0]      # class 2 certain -> full colour
    rgb, arg = bias_map_rgb(post, ["#ff0000", "#00ff00", "#0000ff"])
    assert arg.tolist() == [[0, 1, 2]]
    np.testing.assert_allclose(rgb[0, 2], [0, 0, 1])
    np.testing.assert_allclose(rgb[0, 0], [0.45, 0, 0])
    assert 0.45 < rgb[0, 1, 1] < 1 and rgb[0, 1, 0] == 0 == rgb[0, 1, 2]


# -- CIs over realizations ----------------------------------------------------------------------
def test_bootstrap_ci_over_realizations_covers_a_known_rate_near_nominally():
    rng = np.random.default_rng(11)
    R, K, p, trials = 60, 3, 0.35, 160
    hits = 0
    for t in range(trials):
        c = (rng.random((R, K)) < p).astype(float)
        m = {"correct": c, "p_truth": c, "msde": c, "log10_mgr": rng.exponential(1.0, (R, K))}
        e = bootstrap_track(m, PARAMS, n_boot=400, seed=t)["correct_final"]
        hits += e.low <= p <= e.high
    assert 0.85 <= hits / trials <= 0.99


def test_bootstrap_of_a_constant_is_that_constant_and_inf_stays_inf():
    R, K = 10, 4
    m = {"correct": np.ones((R, K)), "p_truth": np.full((R, K), 0.3), "msde": np.zeros((R, K)),
         "log10_mgr": np.zeros((R, K))}
    m["log10_mgr"][:, -1] = np.inf
    e = bootstrap_track(m, PARAMS, n_boot=50)
    assert (e["correct_final"].value, e["correct_final"].low, e["correct_final"].high) == (1.0, 1.0, 1.0)
    assert e["log10_mgr95_final"].high == np.inf and e["log10_mgr95_overall"].value == np.inf


# -- the main report: the verdict first ---------------------------------------------------------
def test_the_verdict_is_the_first_section_with_context_sentences_and_pooled_cis(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    pop = facts["summary"]["population"]
    assert page.sections[0] == "verdict" and res.sections[0] == "verdict"
    text = res.index.read_text()
    first = text[text.index('id="verdict"'):text.index('id="population"')]
    assert "synthetic data (stand-ins rendered" in first
    # honest counts: targets, tracks (per target), settings, cells, realizations
    assert "3 targets, 6 tracks, 2 per target, 2 localization settings: 12 (target, track, setting) cells" in first
    assert "5 realizations per cell" in first and "held-out top-1 0.940 [" in first
    assert "one training run (classifier.seed = 3)" in first and "viewfuse study" in first
    # The primary metrics' sentences, rendered from summary.json's records, on the first screen; all
    # of them collapsed below.
    recs = pop["records"]
    head = [sentence(r) for r in recs if r["primary"]]
    assert head and {r["metric"] for r in recs if r["primary"]} <= {"correct_final", "confident_error_final"}
    assert len(recs) == 16
    assert page.verdict == head + [sentence(r) for r in recs]
    assert first.index(head[-1]) < first.index('class="summary pooled"') < first.index("All 16 verdict sentences")
    pooled = page.table("pooled")
    assert pooled["section"] == "verdict"
    header, *rows = pooled["rows"]
    assert header[0] == "method" and header[1] == "correct, final"
    assert [r[0] for r in rows] == [labels.method_label(m) for m in labels.ordered_methods(pop["methods"])]
    for r, m in zip(rows, labels.ordered_methods(pop["methods"])):
        for cell, key in zip(r[1:], ("correct_final", "correct_overall", "prob_truth_final", "msde_final",
                                     "log10_mgr95_final")):
            want = pop["pooled"][m][key]
            assert cell == Estimate.of(want).text()
    assert 'class="tag">synthetic data' in text


def test_population_tables_show_paired_differences_per_target_and_ablations(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    pop = facts["summary"]["population"]
    paired = page.table("paired")
    header, *rows = paired["rows"]
    assert header[:5] == ["comparison", "metric", "outcome", "Holm-adjusted outcome", "difference [95 % CI]"]
    first = rows[0]
    d = pop["paired"]["with_uncertainty-model_based"]["correct_final"]
    assert first[0] == "With Uncertainty − Model Based" and first[4] == Estimate.of(d, signed=True).text()
    assert first[2] == [r for r in pop["records"] if r["metric"] == "correct_final"][0]["outcome"]
    assert first[3] == "—"                      # the fake run's records carry no Holm fields: unadjusted
    assert first[5] == f"{100 * d['wins']:.0f} %"
    per = page.table("per-target")["rows"][1:]
    assert len(per) == 3 * 3 and {r[0] for r in per} == {f"{t} (2 tracks)" for t in pop["targets"]}
    abl = page.table("ablations")
    assert abl["section"] == "diagnostics"
    assert abl["rows"][1][0] == "GP noise floor at the dropout variance"    # the override in plain words
    # short, computed outcomes of the headline metrics, worded by the records' renderer, each the
    # one its interval gives
    from reports.main.verdict import HEADLINE
    from reports.shared.records import find, outcome_clauses

    block = pop["ablations"]["models.noise_floor=dropout"]
    a = block["paired"]["with_uncertainty-model_based"]["correct_final"]
    want = "not distinguishable" if a["ci_low"] <= 0 <= a["ci_high"] else ("better" if a["ci_low"] > 0 else "worse")
    recs = [find(block["records"], "with_uncertainty-model_based", m) for m in HEADLINE]
    cell = abl["rows"][1][3]
    assert cell == "; ".join(outcome_clauses([r for r in recs if r], subject=False)) and len(cell) < 300
    said = next((part for part in cell.split("; ") if "correct ratio" in part), cell)   # "<outcome> on ..."
    assert want == recs[0]["outcome"] and said.startswith(f"{want} on")
    assert {"forest.png", "per_target.png"} <= set(res.figures)


def test_gp_fits_at_a_bound_are_one_line_and_a_collapsed_table(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    fits = facts["index"]["diagnostics"]
    n_bound = sum(1 for f in fits if f["at_bound"])
    n_noise = sum(1 for f in fits if any("noise" in a for a in f["at_bound"]))
    text = res.index.read_text()
    assert f"{n_bound} of {len(fits)} GP fits (class × component) ended with a hyperparameter at a bound" in text
    assert f"in {n_noise} the noise variance sits at its lower bound" in text
    hp = page.table("hyperparameters")
    assert hp["collapsed"] and hp["section"] == "diagnostics" and len(hp["rows"]) - 1 == len(fits)
    assert 'class="warn"' not in text.split('id="diagnostics"')[1].split("</section>")[0]


def test_no_table_cell_holds_a_raw_mgr_and_mgr_is_log10_everywhere(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    mgr_tables = 0
    for t in page.tables:
        header = t["rows"][0]
        for j, h in enumerate(header):
            if "MGR" in h:
                mgr_tables += 1
                assert "log10" in h, h
                for row in t["rows"][1:]:
                    assert all(abs(float(x)) < 1e6 for x in re.findall(NUM, row[j])), row[j]
    assert mgr_tables >= 5
    text = res.index.read_text()
    assert "log MGR" not in text.replace("log10 MGR", "") and "(ours)" not in text


def test_single_track_cis_over_realizations_agree_with_an_independent_computation(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    want = facts["summary"]["experiments"]["sensitivity"]
    header, *rows = page.table("sensitivity")["rows"]
    assert header[-1] == "realizations" and len(rows) == 3 * 3
    short = {labels.method_label(m, short=True): m for m in labels.methods()}
    for r in rows:
        m = want[r[0]][short[r[1]]]
        for cell, key in zip(r[2:6], ("correct_final", "correct_overall", "log10_mgr95_final", "log10_mgr95_overall")):
            v, lo, hi = estimate(cell)
            assert v == pytest.approx(m[key], rel=2e-3, abs=shown_tol(cell)) and lo <= hi, (r, key)
        assert int(r[-1]) == facts["R"]


def test_every_figure_is_written_and_the_page_works_from_disk(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    out = res.index.parent
    assert set(page.imgs) == set(res.figures) == {p.name for p in out.glob("*.png")}
    for name in page.imgs:
        assert "/" not in name and (out / name).read_bytes()[:8] == PNG_MAGIC
    text = res.index.read_text()
    assert page.scripts == 0 and "http://" not in text and "https://" not in text
    assert all(h.startswith("#") for h in page.links)
    assert page.sections == ["verdict", "methods", "limitations", "seeds", "population", "diagnostics", "showcase",
                             "track", "randomized", "sensitivity", "bias-maps", "gp", "glossary", "reproduce",
                             "details"]


def test_names_say_what_they_are_and_run_details_show_skips(rendered_run):
    facts, res = rendered_run
    page = parse(res.index)
    text = res.index.read_text()
    assert "output 2 of the classifier: its score for the texture family &#x27;chevron&#x27;" in text
    skips = [t for t in page.tables if t["rows"][0] == ["stage", "what", "skipped", "reasons"]][0]["rows"][1:]
    assert ["features", "bigbird", "2", "mask is empty (2)"] in skips
    assert ["evaluate", "target mahatma_rice", "1", "no track of 5 views sees it (3 views)"] in skips
    assert "evaluate.seed" in text and "numpy" in text and "3.61 cm" in text and "(rule: top_mean)" in text
    assert "scans Home_001_1, Home_002_1" in text  # the subtitle names every scan tracks came from


# -- older runs, partial runs, bad input ---------------------------------------------------------
def test_an_older_run_says_it_has_no_verdict_and_still_shows_log10(tmp_path):
    facts = write_fake_run(tmp_path / "run", legacy=True, experiments=("randomized",), K=3, R=4)
    assert "target" not in pq.read_schema(facts["evaluate"] / "results.parquet").names
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False, n_boot=50)
    page = parse(res.index)
    assert page.sections[0] == "verdict" and "population" not in page.sections
    assert any("has no population evaluation" in n for n in res.notes)
    rows = page.table("randomized")["rows"][1:]
    want = facts["summary"]["experiments"]["randomized"]
    wu = [r for r in rows if r[1] == "With Uncertainty"][0]
    assert estimate(wu[4])[0] == pytest.approx(want[wu[0]]["with_uncertainty"]["log10_mgr95_final"], rel=2e-3,
                                               abs=shown_tol(wu[4]))


def test_sections_appear_only_for_existing_outputs(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("biased",), methods=("with_uncertainty", "model_based"))
    (facts["run"] / "models" / "index.json").unlink()
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False)
    page = parse(res.index)
    assert sorted(res.figures) == ["biased_ptruth.png", "track.png"]
    assert not {"randomized", "bias-maps", "gp", "sensitivity"} & set(page.sections)
    assert "models/index.json not found" in res.index.read_text()


def test_a_natural_log_mgr_table_is_refused_naming_the_file(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized",), T=1, tracks=1, R=3, K=3, ablation=False)
    path = facts["evaluate"] / "results.parquet"
    t = pq.read_table(path)
    pq.write_table(t.rename_columns(["log_mgr" if c == "log10_mgr" else c for c in t.column_names]), path)
    with pytest.raises(BadInputError, match=r"results\.parquet: missing column\(s\) log10_mgr"):
        build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False)


def test_infinite_log_mgr_is_drawn_and_reported(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized",), T=1, tracks=1, R=4, K=3, ablation=False)
    path = facts["evaluate"] / "results.parquet"
    t = pq.read_table(path)
    lm = t.column("log10_mgr").to_numpy().copy()
    lm[0] = np.inf
    pq.write_table(t.set_column(t.column_names.index("log10_mgr"), "log10_mgr", [lm]), path)
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False, n_boot=50)
    assert any("1 infinite value" in n for n in res.notes) and "1 infinite value" in res.index.read_text()


def test_png_output_is_deterministic(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("biased", "bias_maps"), K=3, B=5, T=1, tracks=1)
    a = build_main_report(facts["run"], tmp_path / "a", dpi=40, progress=False)
    b = build_main_report(facts["run"], tmp_path / "b", dpi=40, progress=False)
    for name in a.figures:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_missing_or_empty_evaluate_folder_is_an_error_naming_it(tmp_path):
    with pytest.raises(BadInputError, match="evaluate output folder not found"):
        build_main_report(tmp_path / "nope", tmp_path / "out", progress=False)
    (tmp_path / "empty" / "evaluate").mkdir(parents=True)
    with pytest.raises(BadInputError, match=r"evaluate.*no evaluate outputs"):
        build_main_report(tmp_path / "empty", tmp_path / "out", progress=False)


def test_corrupt_or_incomplete_inputs_name_the_file_and_problem(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized", "bias_maps"), R=3, K=3, B=4, T=1, tracks=1)
    run, ev = facts["run"], facts["evaluate"]
    res = ev / "results.parquet"
    good = res.read_bytes()
    res.write_bytes(b"not parquet")
    with pytest.raises(BadInputError, match=r"results\.parquet: not a readable Parquet"):
        build_main_report(run, tmp_path / "out", progress=False)
    pq.write_table(pq.read_table(io.BytesIO(good)).drop(["log10_mgr"]), res)
    with pytest.raises(BadInputError, match=r"results\.parquet: missing column\(s\) log10_mgr"):
        build_main_report(run, tmp_path / "out", progress=False)
    res.write_bytes(good)
    # Object arrays would need pickle to load: refused, with the file named.
    np.savez(ev / "bias_maps.npz", bias_x=np.zeros(4), bias_y=np.zeros(4),
             posterior=np.zeros((3, 4, 4, 4)), classes=np.array(["a", None], dtype=object))
    with pytest.raises(BadInputError, match=r"bias_maps\.npz: holds object arrays, which would need unpickling"):
        build_main_report(run, tmp_path / "out", progress=False)
    np.savez(ev / "bias_maps.npz", bias_x=np.zeros(4), bias_y=np.zeros(4), posterior=np.zeros((3, 4, 4, 4)))
    whole = (ev / "bias_maps.npz").read_bytes()
    (ev / "bias_maps.npz").write_bytes(whole[: len(whole) // 2])  # a copy cut short
    with pytest.raises(BadInputError, match=r"bias_maps\.npz: not a valid \.npz file"):
        build_main_report(run, tmp_path / "out", progress=False)
    np.savez(ev / "bias_maps.npz", bias_x=np.zeros(4), bias_y=np.zeros(5), posterior=np.zeros((3, 4, 4, 4)))
    with pytest.raises(BadInputError, match=r"bias_maps\.npz: posterior must be \(K, C, 5, 4\)"):
        build_main_report(run, tmp_path / "out", progress=False)
    (ev / "bias_maps.npz").unlink()
    (run / "classifier" / "card.json").write_text("{not json")
    with pytest.raises(BadInputError, match=r"card\.json: not valid JSON"):
        build_main_report(run, tmp_path / "out", progress=False)


def test_hyperparameter_table_falls_back_to_the_index_table_without_fit_diagnostics(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("biased",), K=3, T=1, tracks=1)
    index = dict(facts["index"])
    header, rows, warns = hyperparameter_table(index)
    assert header[:3] == ["class", "component", "component name"] and "random_state" not in header
    assert "score std over views" in header
    assert any(w.endswith("length_scale at upper bound") for w in warns)
    index["hyperparameters"] = {f["class"]: {} for f in index["diagnostics"]}
    for f in index["diagnostics"]:
        index["hyperparameters"][f["class"]][str(f["component"])] = {"noise": f["noise"]}
    del index["diagnostics"]
    header2, rows2, warns2 = hyperparameter_table(index)
    assert len(rows2) == len(rows) and warns2 == []


def test_dump_toml_nests_tables():
    text = dump_toml({"run": {"name": "x", "threads": 0}, "evaluate": {"seed": 1, "biased": {"bias_m": [-0.3, 0.2]}}})
    assert '[run]\nname = "x"\nthreads = 0' in text
    assert "[evaluate.biased]\nbias_m = [-0.3, 0.2]" in text


# -- the stage ----------------------------------------------------------------------------------
def test_report_stage_renders_from_existing_results(tmp_config, tmp_path):
    from stages.framework.runner import StageContext
    from stages.report import run
    cfg = tmp_config({"report": {"dpi": 40, "title": "Stage test"}})
    write_fake_run(cfg.run_dir, experiments=("biased", "randomized"), R=3, K=3, T=2, tracks=1)
    before = {p.name: p.read_bytes() for p in (cfg.run_dir / "evaluate").iterdir()}
    out = tmp_path / "stage_out"
    out.mkdir()
    ctx = StageContext(cfg=cfg, stage="report", out=out)
    summary = run(ctx)
    assert str(cfg.stage_dir("report") / "index.html") in summary
    text = (out / "index.html").read_text()
    assert "<title>Stage test</title>" in text and "[report]" in text and "dpi = 40" in text
    assert ctx.extra["sections"][0] == "verdict"
    assert ctx.extra["figures"] and all((out / f).is_file() for f in ctx.extra["figures"])
    # It only read the evaluate outputs: nothing there changed or was added.
    assert {p.name: p.read_bytes() for p in (cfg.run_dir / "evaluate").iterdir()} == before
    assert json.loads((cfg.run_dir / "evaluate" / "summary.json").read_text())["population"]["n_targets"] == 2


def test_an_empty_per_target_block_is_said_not_drawn(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized",), T=2, tracks=2, R=3, K=3, ablation=False)
    path = facts["evaluate"] / "summary.json"
    summary = json.loads(path.read_text())
    summary["population"]["per_target"] = {}
    path.write_text(json.dumps(summary))
    res = build_main_report(facts["run"], tmp_path / "out", dpi=40, progress=False, n_boot=50)
    assert "per_target.png" not in res.figures and "forest.png" in res.figures
    assert any("per-target block is empty" in n for n in res.notes)
    assert not [t for t in parse(res.index).tables if "per-target" in t["cls"].split()]
