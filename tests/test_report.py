"""Report: the HTML builder, the figure helpers, and the main report on fake evaluate outputs."""
from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from loaders.errors import BadInputError
from reports.figures import METHOD_STYLE, new_figure, percentile_bands, save
from reports.html import HtmlReport
from reports.main_report import (bias_map_rgb, build_main_report, dump_toml, summary_from_results,
                                 read_results)
from tests.report_fixtures import CLASSES, write_fake_run

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class _Page(HTMLParser):
    """Collects <img src>, tables (class + cell text) and section ids from a page."""

    def __init__(self):
        super().__init__()
        self.imgs, self.tables, self.ids, self.scripts, self.links = [], [], [], 0, []
        self._cell = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a.get("src"))
        elif tag == "table":
            self.tables.append({"cls": a.get("class", ""), "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "script":
            self.scripts += 1
        elif tag in ("link", "a"):
            self.links.append(a.get("href", ""))
        if "id" in a:
            self.ids.append(a["id"])

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1]["rows"][-1].append("".join(self._cell))
            self._cell = None


def parse(path) -> _Page:
    p = _Page()
    p.feed(Path(path).read_text())
    return p


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    facts = write_fake_run(root / "run")
    res = build_main_report(facts["evaluate"], facts["models"], root / "out", run_name="fake",
                            config={"evaluate": {"seed": 7, "biased": {"bias_m": [-0.3, 0.2]}},
                                    "report": {"dpi": 60}},
                            timings={"models": 1.5, "evaluate": 12.0}, dpi=60, progress=False)
    return facts, res, parse(res.index)


# -- HtmlReport ---------------------------------------------------------------------------------
def test_html_escapes_text_and_keeps_anchors_unique(tmp_path):
    r = HtmlReport("A <b> title", "sub & more")
    r.section("Results")
    r.paragraph("x < y & <script>alert(1)</script>")
    r.section("Results")
    r.table(["a", "b"], [[1, 0.123456], [None, float("nan")], [float("inf"), True]], cls="summary")
    r.preformatted("<raw>")
    r.write(tmp_path / "index.html")
    text = (tmp_path / "index.html").read_text()
    page = parse(tmp_path / "index.html")
    assert "<script>" not in text and page.scripts == 0
    assert "A &lt;b&gt; title" in text and "&lt;raw&gt;" in text
    assert page.ids.count("results") == 1 and "results-2" in page.ids
    rows = page.tables[0]["rows"]
    assert rows[1] == ["1", "0.1235"] and rows[2] == ["—", "n/a"] and rows[3] == ["∞", "yes"]
    assert [p.name for p in tmp_path.iterdir()] == ["index.html"]  # no temp file left behind


def test_html_rejects_bad_tables_and_non_relative_figures():
    r = HtmlReport("t")
    with pytest.raises(ValueError, match="row 0 has 1 cells"):
        r.table(["a", "b"], [[1]])
    for bad in ("http://example.com/a.png", "/abs/a.png", "../up.png", "data:image/png;base64,AA"):
        with pytest.raises(ValueError, match="relative"):
            r.figure(bad, "c")
    r.figure("ok.png", "fine")
    assert r.figures == ["ok.png"]


# -- figure helpers -----------------------------------------------------------------------------
def test_percentile_bands_match_numpy_percentiles():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(41, 5)).cumsum(axis=1)
    fig, ax = new_figure()
    percentile_bands(ax, np.arange(5), v, METHOD_STYLE["model_based"]["color"], "MB")
    polys = ax.collections
    assert len(polys) == 4  # 10–90, 20–80, 30–70, 40–60
    # The widest band's outline spans exactly the 10th..90th percentiles per step.
    verts = polys[0].get_paths()[0].vertices
    lo, hi = np.percentile(v, 10, axis=0), np.percentile(v, 90, axis=0)
    for k in range(5):
        ys = verts[np.isclose(verts[:, 0], k), 1]
        assert np.isclose(ys.min(), lo[k]) and np.isclose(ys.max(), hi[k])
    med = ax.lines[-1].get_ydata()
    np.testing.assert_allclose(med, np.median(v, axis=0))
    # The median line is darker than the band colour.
    assert sum(ax.lines[-1].get_color()) < sum(polys[0].get_facecolor()[0][:3])
    with pytest.raises(ValueError, match="K = 4"):
        percentile_bands(ax, np.arange(4), v, "k")


def test_save_writes_png_atomically(tmp_path):
    fig, ax = new_figure(2, 2)
    ax.plot([0, 1], [1, 0])
    save(fig, tmp_path / "a.png", dpi=40)
    assert (tmp_path / "a.png").read_bytes()[:8] == PNG_MAGIC
    import os
    mask = os.umask(0o022)
    try:
        save(fig, tmp_path / "a.png", dpi=40)  # replaces the file atomically
    finally:
        os.umask(mask)
    assert (tmp_path / "a.png").stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]
    with pytest.raises(ValueError, match=".png"):
        save(fig, tmp_path / "a.jpg", dpi=40)


def test_bias_map_rgb_hue_is_argmax_and_brightness_grows_with_probability():
    C = 3
    post = np.zeros((C, 1, 3))
    post[:, 0, 0] = 1 / C                # uniform -> darkest
    post[:, 0, 1] = [0.2, 0.7, 0.1]      # class 1 wins, fairly sure
    post[:, 0, 2] = [0.0, 0.0, 1.0]      # class 2 certain -> full colour
    cols = ["#ff0000", "#00ff00", "#0000ff"]
    rgb, arg = bias_map_rgb(post, cols)
    assert arg.tolist() == [[0, 1, 2]]
    np.testing.assert_allclose(rgb[0, 2], [0, 0, 1])
    np.testing.assert_allclose(rgb[0, 0], [0.25, 0, 0])
    assert 0.25 < rgb[0, 1, 1] < 1 and rgb[0, 1, 0] == 0 == rgb[0, 1, 2]


# -- the main report ----------------------------------------------------------------------------
def test_report_writes_every_figure_it_references(rendered):
    facts, res, page = rendered
    out = res.index.parent
    assert set(page.imgs) == set(res.figures)
    assert len(res.figures) == 8
    for name in page.imgs:
        assert "/" not in name and (out / name).read_bytes()[:8] == PNG_MAGIC
    assert page.scripts == 0
    # Works from disk: no external resources, only in-page anchors.
    text = res.index.read_text()
    assert "http://" not in text and "https://" not in text
    assert all(h.startswith("#") for h in page.links)
    for sec in ("overview", "gp", "biased", "randomized", "sensitivity", "bias-maps",
                "hyperparameters", "details"):
        assert sec in page.ids


def test_summary_table_holds_the_summary_json_values(rendered):
    facts, res, page = rendered
    summ = [t for t in page.tables if t["cls"] == "summary"]
    assert len(summ) == 1
    header, *rows = summ[0]["rows"]
    assert header[:3] == ["setting", "method", "correct ratio, final"]
    expect = facts["summary"]["experiments"]["randomized"]["sigma=0.30 m"]
    assert len(rows) == len(expect) == 3
    labels = {v["label"]: k for k, v in METHOD_STYLE.items()}
    for r in rows:
        m = expect[labels[r[1]]]
        got = [float(x) for x in r[2:8]]
        want = [m[k] for k in ("correct_final", "correct_overall", "mgr75_final", "mgr95_final",
                               "mgr75_overall", "mgr95_overall")]
        np.testing.assert_allclose(got, want, rtol=1e-3)
        assert int(r[8]) == facts["R"]


def test_report_lists_hyperparameters_warnings_seeds_and_config(rendered):
    facts, res, page = rendered
    text = res.index.read_text()
    hp = [t for t in page.tables if "length scale ℓ" in t["rows"][0]]
    assert len(hp) == 1 and len(hp[0]["rows"]) - 1 == len(facts["index"]["diagnostics"])
    assert "length_scale at upper bound 10" in text            # the fit warning is shown
    assert "evaluate.seed" in text and "[evaluate.biased]" in text
    assert "numpy" in text and "matplotlib" in text
    assert "3.6 cm" in text                                    # object position error (est vs truth)
    assert "(rule: top_mean)" in text


def test_hyperparameters_fall_back_to_the_index_table_without_fit_diagnostics(tmp_path):
    from reports.main_report import hyperparameter_table
    facts = write_fake_run(tmp_path / "run", experiments=("biased",), K=3)
    index = dict(facts["index"])
    header, rows, warns = hyperparameter_table(index)
    assert header[:2] == ["class", "component"] and "random_state" not in header
    assert warns == ["crystal_hot_sauce / 3: length_scale at upper bound 10"]
    del index["diagnostics"]
    header2, rows2, warns2 = hyperparameter_table(index)
    assert len(rows2) == len(rows) and warns2 == []
    ls = header.index("length scale ℓ")
    assert [r[header2.index("length scale ℓ")] for r in rows2] == [r[ls] for r in rows]


def test_sections_appear_only_for_existing_outputs(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("biased",), methods=("with_uncertainty", "model_based"))
    res = build_main_report(facts["evaluate"], facts["models"], tmp_path / "out", dpi=40, progress=False)
    page = parse(res.index)
    assert sorted(res.figures) == ["biased_ptruth.png", "track.png"]
    assert "randomized" not in page.ids and "bias-maps" not in page.ids and "gp" not in page.ids
    assert not [t for t in page.tables if t["cls"] == "summary"]
    assert sorted(p.name for p in res.index.parent.glob("*.png")) == sorted(res.figures)


def test_summary_from_results_agrees_with_an_independent_computation(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized", "sensitivity"), R=5, K=4)
    df, meta = read_results(facts["evaluate"] / "results.parquet")
    assert meta["classes"] == list(CLASSES) and meta["seed"] == "0"
    for exp in ("randomized", "sensitivity"):
        got = summary_from_results(df[df["experiment"] == exp])
        want = facts["summary"]["experiments"][exp]
        assert got.keys() == want.keys()
        for s in want:
            for m in want[s]:
                for k, v in want[s][m].items():
                    assert got[s][m][k] == pytest.approx(v, rel=1e-9), (exp, s, m, k)


def test_summary_is_computed_when_summary_json_lacks_it(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized",), R=4, K=3)
    (facts["evaluate"] / "summary.json").unlink()
    res = build_main_report(facts["evaluate"], facts["models"], tmp_path / "out", dpi=40, progress=False)
    rows = [t for t in parse(res.index).tables if t["cls"] == "summary"][0]["rows"][1:]
    want = facts["summary"]["experiments"]["randomized"]["sigma=0.30 m"]["model_based"]["correct_final"]
    mb = [r for r in rows if r[1] == METHOD_STYLE["model_based"]["label"]][0]
    assert float(mb[2]) == pytest.approx(want, rel=1e-3)


def test_infinite_log_mgr_is_drawn_and_reported(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized",), R=4, K=3)
    path = facts["evaluate"] / "results.parquet"
    t = pq.read_table(path)
    lm = t.column("log_mgr").to_numpy().copy()
    lm[0] = np.inf
    t = t.set_column(t.column_names.index("log_mgr"), "log_mgr", [lm])
    pq.write_table(t, path)
    res = build_main_report(facts["evaluate"], None, tmp_path / "out", dpi=40, progress=False)
    assert any("1 infinite value" in n for n in res.notes)
    assert "1 infinite value" in res.index.read_text()


def test_png_output_is_deterministic(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("biased", "bias_maps"), K=3, B=5)
    a = build_main_report(facts["evaluate"], facts["models"], tmp_path / "a", dpi=40, progress=False)
    b = build_main_report(facts["evaluate"], facts["models"], tmp_path / "b", dpi=40, progress=False)
    for name in a.figures:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


# -- bad input ----------------------------------------------------------------------------------
def test_missing_or_empty_evaluate_folder_is_an_error_naming_it(tmp_path):
    with pytest.raises(BadInputError, match="evaluate output folder not found"):
        build_main_report(tmp_path / "nope", None, tmp_path / "out", progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BadInputError, match=r"empty.*no evaluate outputs"):
        build_main_report(tmp_path / "empty", None, tmp_path / "out", progress=False)


def test_corrupt_or_incomplete_inputs_name_the_file_and_problem(tmp_path):
    facts = write_fake_run(tmp_path / "run", experiments=("randomized", "bias_maps"), R=3, K=3, B=4)
    ev = facts["evaluate"]
    res = ev / "results.parquet"
    good = res.read_bytes()
    res.write_bytes(b"not parquet")
    with pytest.raises(BadInputError, match=r"results\.parquet: not a readable Parquet"):
        build_main_report(ev, None, tmp_path / "out", progress=False)
    t = pq.read_table(__import__("io").BytesIO(good)).drop(["log_mgr"])
    pq.write_table(t, res)
    with pytest.raises(BadInputError, match=r"results\.parquet: missing column\(s\) log_mgr"):
        build_main_report(ev, None, tmp_path / "out", progress=False)
    res.write_bytes(good)

    # Object arrays would need pickle to load: refused, with the file named.
    np.savez(ev / "bias_maps.npz", bias_x=np.zeros(4), bias_y=np.zeros(4),
             posterior=np.zeros((3, 4, 4, 4)), classes=np.array(["a", None], dtype=object))
    with pytest.raises(BadInputError, match=r"bias_maps\.npz: cannot read without pickle"):
        build_main_report(ev, None, tmp_path / "out", progress=False)
    np.savez(ev / "bias_maps.npz", bias_x=np.zeros(4), bias_y=np.zeros(5), posterior=np.zeros((3, 4, 4, 4)))
    with pytest.raises(BadInputError, match=r"bias_maps\.npz: posterior must be \(K, C, 5, 4\)"):
        build_main_report(ev, None, tmp_path / "out", progress=False)
    (ev / "bias_maps.npz").unlink()
    (ev / "track.json").write_text("{not json")
    with pytest.raises(BadInputError, match=r"track\.json: not valid JSON"):
        build_main_report(ev, None, tmp_path / "out", progress=False)


def test_dump_toml_nests_tables():
    text = dump_toml({"run": {"name": "x", "threads": 0}, "evaluate": {"seed": 1, "biased": {"bias_m": [-0.3, 0.2]}}})
    assert '[run]\nname = "x"\nthreads = 0' in text
    assert "[evaluate.biased]\nbias_m = [-0.3, 0.2]" in text


# -- the stage ----------------------------------------------------------------------------------
def test_report_stage_renders_from_existing_results(tmp_config, tmp_path):
    from stages.report import run
    from stages.runner import StageContext
    cfg = tmp_config({"report": {"dpi": 40, "title": "Stage test"}})
    write_fake_run(cfg.run_dir, experiments=("biased", "randomized"), R=4, K=3)
    before = {p.name: p.read_bytes() for p in (cfg.run_dir / "evaluate").iterdir()}
    out = tmp_path / "stage_out"
    out.mkdir()
    ctx = StageContext(cfg=cfg, stage="report", out=out)
    summary = run(ctx)
    assert str(cfg.stage_dir("report") / "index.html") in summary
    text = (out / "index.html").read_text()
    assert "<title>Stage test</title>" in text
    assert "[report]" in text and "dpi = 40" in text       # the resolved config is dumped
    assert ctx.extra["figures"] and all((out / f).is_file() for f in ctx.extra["figures"])
    # It only read the evaluate outputs: nothing there changed or was added.
    assert {p.name: p.read_bytes() for p in (cfg.run_dir / "evaluate").iterdir()} == before


def test_mgr_cells_show_an_overflowing_ratio_from_its_log10():
    from reports.html import mgr_cell
    assert mgr_cell(3.5, 0.544) == 3.5
    assert mgr_cell(None, 3530.30103) == "2e+3530"
    assert float(mgr_cell(None, 400.0)) == float("inf")   # still parses as a (huge) number
    assert mgr_cell(None, None) is None
