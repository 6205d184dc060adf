"""The report page in a real browser (headless Chromium, 1400 px wide): the verdict is the first
section and on the first screen, every image loads, no table cell holds a raw MGR, no table
scrolls sideways, every figure is shown at a size where its smallest text is >= 11 px and none has
overlapping tick labels (the figure's own text-layout check, carried on the <img>); a full-page
screenshot at 1400 px is kept in the test's output folder.

The page itself carries no script. The test renders a COPY of it into which it injected a tiny
on-load check that writes its findings into the DOM; ``--dump-dom`` then hands the DOM back.
Skipped, visibly, where Chromium is not installed (CI installs Debian's ``chromium``).
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.support.report_fixtures import rendered_run, rendered_run_default_dpi  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

WIDTH, HEIGHT = 1400, 1000
# A table column is an MGR column when its header says MGR; every number in its cells must be a
# log10 value (|x| <= 1e6), never a raw ratio such as 6.81e+77.
CHECK = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                   .map(function (i) { return i.getAttribute('src'); });
  var raw = [], mgrColumns = 0;
  document.querySelectorAll('table').forEach(function (t) {
    var heads = Array.prototype.map.call(t.querySelectorAll('thead th'), function (h) { return h.textContent; });
    heads.forEach(function (h, j) {
      if (h.indexOf('MGR') < 0) return;
      mgrColumns += 1;
      t.querySelectorAll('tbody tr').forEach(function (r) {
        var c = r.children[j];
        var nums = (c ? c.textContent : '').match(/[-+]?\\d+(\\.\\d+)?(e[-+]?\\d+)?/gi) || [];
        nums.forEach(function (x) { if (Math.abs(parseFloat(x)) > 1e6) raw.push(c.textContent); });
      });
    });
  });
  var scrolling = [];
  document.querySelectorAll('details').forEach(function (d) { d.open = true; });  // collapsed tables too
  document.querySelectorAll('.tablewrap').forEach(function (w) {
    if (w.scrollWidth > w.clientWidth + 1) scrolling.push(w.querySelector('table').className);
  });
  var small = [], overlaps = [];
  imgs.forEach(function (i) {
    var px = parseFloat(i.getAttribute('data-min-font-px') || '0');
    var scale = i.naturalWidth ? i.getBoundingClientRect().width / i.naturalWidth : 0;
    if (!(px * scale >= 11)) small.push(i.getAttribute('src') + ': ' + (px * scale).toFixed(1) + ' px');
    if (i.getAttribute('data-tick-overlaps') !== '0') overlaps.push(i.getAttribute('src'));
  });
  var first = document.querySelector('main section');
  var verdict = document.getElementById('verdict');
  var d = document.createElement('div');
  d.id = 'vf-check';
  d.setAttribute('data-result', JSON.stringify({
    images: imgs.length, broken: broken, first_section: first ? first.id : null,
    verdict_top: verdict ? verdict.getBoundingClientRect().top : null,
    mgr_columns: mgrColumns, raw_mgr: raw, scrolling: scrolling, small_text: small, overlaps: overlaps}));
  document.body.appendChild(d);
});
</script>"""

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-quic", "--no-first-run", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", f"--window-size={WIDTH},{HEIGHT}"]


def _chromium() -> str:
    exe = shutil.which("chromium")
    if exe is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    return exe


def _check_in_browser(exe: str, page_dir: Path, profile: Path) -> dict:
    """Load a copy of page_dir/index.html with the check injected; return its findings."""
    html = (page_dir / "index.html").read_text()
    assert "</body>" in html
    probe = page_dir / "_probe.html"
    probe.write_text(html.replace("</body>", CHECK + "</body>", 1))
    proc = subprocess.run([exe, *FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=5000",
                           "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=180)
    probe.unlink()
    m = re.search(r'id="vf-check"[^>]*data-result="([^"]*)"', proc.stdout)
    assert m, f"no check result in the dumped DOM (rc {proc.returncode}): {proc.stderr[-2000:]}"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))


@pytest.fixture(scope="module")
def page(rendered_run, tmp_path_factory):  # noqa: F811 (the imported fixture)
    exe = _chromium()
    facts, res = rendered_run
    return exe, tmp_path_factory.mktemp("browser"), res


def test_verdict_first_every_image_loads_and_no_raw_mgr(page):
    exe, root, res = page
    found = _check_in_browser(exe, res.index.parent, root / "profile")
    assert found["first_section"] == "verdict"
    assert 0 <= found["verdict_top"] < HEIGHT / 2          # on the first screen, near its top
    assert found["images"] == len(res.figures) > 0 and found["broken"] == []
    assert found["mgr_columns"] >= 5 and found["raw_mgr"] == []


@pytest.fixture(scope="module")
def page110(rendered_run_default_dpi, tmp_path_factory):  # noqa: F811
    exe = _chromium()
    _, res = rendered_run_default_dpi
    return exe, tmp_path_factory.mktemp("browser110"), res


def test_at_1400px_tables_fit_and_every_figure_is_legible_without_overlapping_ticks(page110):
    exe, root, res = page110
    found = _check_in_browser(exe, res.index.parent, root / "profile")
    assert found["images"] == len(res.figures) > 0 and found["broken"] == []
    assert found["scrolling"] == [], "tables wider than the page at 1400 px"
    assert found["small_text"] == [] and found["overlaps"] == []
    # The page as a reviewer sees it, kept with the test's output.
    shot = root / "report_1400px.png"
    subprocess.run([exe, *FLAGS[:-1], "--window-size=1400,6000", f"--user-data-dir={root / 'profile4'}",
                    f"--screenshot={shot}", res.index.as_uri()], capture_output=True, text=True, timeout=180)
    assert shot.is_file()
    print(f"screenshot: {shot}")


def test_the_legibility_checks_catch_small_text_overlaps_and_a_scrolling_table(page110):
    exe, root, res = page110
    copy = root / "shrunk"
    shutil.copytree(res.index.parent, copy)
    html = (copy / "index.html").read_text()
    html = html.replace('data-tick-overlaps="0"', 'data-tick-overlaps="2"', 1)
    html = html.replace("<img ", '<img style="width:300px" ', 1)              # a figure shrunk below legibility
    html = html.replace('<div class="tablewrap">', '<div class="tablewrap"><div style="width:3000px">x</div>', 1)
    (copy / "index.html").write_text(html)
    found = _check_in_browser(exe, copy, root / "profile5")
    assert len(found["overlaps"]) == 1 and len(found["small_text"]) >= 1 and len(found["scrolling"]) == 1


def test_the_checks_catch_a_missing_image_a_raw_mgr_and_a_late_verdict(page):
    # Guard against checks that always pass: break a copy of the page three ways.
    exe, root, res = page
    copy = root / "broken"
    shutil.copytree(res.index.parent, copy)
    (copy / res.figures[0]).unlink()
    html = (copy / "index.html").read_text()
    html = re.sub(r'(<td class="num">)(<span class="nw">[^<]*</span> <span class="nw">\[[^<]*</span>)(</td></tr>)',
                  r"\g<1>6.810e+77\g<3>", html, count=1)
    start = html.index('<section id="verdict">')
    end = html.index("</section>", start) + len("</section>")
    verdict = html[start:end]
    html = html[:start] + html[end:]
    html = html.replace("</main>", verdict + "</main>", 1)       # the verdict moved to the end
    (copy / "index.html").write_text(html)
    found = _check_in_browser(exe, copy, root / "profile2")
    assert found["broken"] == [res.figures[0]]
    assert found["raw_mgr"] == ["6.810e+77"]
    assert found["first_section"] != "verdict" and found["verdict_top"] > HEIGHT


def test_screenshot_at_1400px_renders_content(page):
    import matplotlib.image as mpimg
    exe, root, res = page
    shot = root / "screenshot.png"
    proc = subprocess.run([exe, *FLAGS, f"--user-data-dir={root / 'profile3'}", f"--screenshot={shot}",
                           res.index.as_uri()], capture_output=True, text=True, timeout=180)
    assert shot.is_file(), f"no screenshot (rc {proc.returncode}): {proc.stderr[-2000:]}"
    img = mpimg.imread(shot)
    assert img.shape[:2] == (HEIGHT, WIDTH)
    # A rendered page has a dark header band and varied content, not a blank canvas.
    assert img[:40, :, :3].mean() < 0.3
    assert np.unique((img[::7, ::7, :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0).shape[0] > 50
