"""The report page in a real browser (headless Chromium): every image loads, the table is there.

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

from reports.main_report import build_main_report
from tests.report_fixtures import write_fake_run

CHECK = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                   .map(function (i) { return i.getAttribute('src'); });
  var d = document.createElement('div');
  d.id = 'vf-check';
  d.setAttribute('data-result', JSON.stringify({
    images: imgs.length, broken: broken,
    summary_tables: document.querySelectorAll('table.summary').length,
    summary_rows: Array.prototype.map.call(document.querySelectorAll('table.summary'),
                  function (t) { return t.querySelectorAll('tbody tr').length; })}));
  document.body.appendChild(d);
});
</script>"""

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-quic", "--no-first-run", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars"]


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
                           "--dump-dom", probe.as_uri()],
                          capture_output=True, text=True, timeout=180)
    probe.unlink()
    m = re.search(r'id="vf-check"[^>]*data-result="([^"]*)"', proc.stdout)
    assert m, f"no check result in the dumped DOM (rc {proc.returncode}): {proc.stderr[-2000:]}"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    exe = _chromium()
    root = tmp_path_factory.mktemp("browser")
    facts = write_fake_run(root / "run", K=5, R=8, B=7)
    res = build_main_report(facts["evaluate"], facts["models"], root / "out", dpi=60,
                            run_name="browser-test", progress=False)
    return exe, root, res


def test_every_image_loads_and_the_summary_table_is_present(page):
    exe, root, res = page
    found = _check_in_browser(exe, res.index.parent, root / "profile")
    assert found["images"] == len(res.figures) > 0
    assert found["broken"] == []
    # Randomized (3 methods) and sensitivity (3 sigmas x 3 methods) summary tables.
    assert found["summary_tables"] == 2 and found["summary_rows"] == [3, 9]


def test_the_check_catches_a_missing_image(page):
    # Guard against a check that always passes: remove one PNG from a copy of the page.
    exe, root, res = page
    copy = root / "broken"
    shutil.copytree(res.index.parent, copy)
    (copy / res.figures[0]).unlink()
    found = _check_in_browser(exe, copy, root / "profile2")
    assert found["broken"] == [res.figures[0]]


def test_screenshot_renders_content(page):
    import matplotlib.image as mpimg
    exe, root, res = page
    shot = root / "screenshot.png"
    proc = subprocess.run([exe, *FLAGS, f"--user-data-dir={root / 'profile3'}", "--window-size=1200,3000",
                           f"--screenshot={shot}", res.index.as_uri()],
                          capture_output=True, text=True, timeout=180)
    assert shot.is_file(), f"no screenshot (rc {proc.returncode}): {proc.stderr[-2000:]}"
    img = mpimg.imread(shot)
    assert img.shape[:2] == (3000, 1200)
    # A rendered page has a dark header band and varied content, not a blank canvas.
    assert img[:40, :, :3].mean() < 0.3
    assert np.unique((img[::7, ::7, :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0).shape[0] > 50
