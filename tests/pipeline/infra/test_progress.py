"""Progress output: bars on a terminal only; a log gets a few plain lines and no carriage returns."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


LOOP = """
import logging, sys
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
from pipeline.infra import progress
progress.LOG_AFTER_S = 0.0
progress.set_mode(sys.argv[1])
log = logging.getLogger("viewfuse.test")
with progress.redirect_logging():
    for i in progress.bar(range(400), desc="outer", unit="step"):
        if i == 200:
            log.info("halfway message")
    with progress.bar(total=50, desc="inner", leave=False) as b:
        for _ in range(50):
            b.update(1)
progress.echo("[stage] done")
"""


@pytest.mark.parametrize("mode", ["auto", "off"])
def test_redirected_output_has_no_carriage_returns(tmp_path, mode):
    log = tmp_path / "log"
    with open(log, "wb") as fh:
        subprocess.run([sys.executable, "-c", LOOP, mode], cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    text = log.read_bytes().decode()  # not read_text(): it would turn \r into \n
    assert "\r" not in text and "\x1b[" not in text
    outer = [ln for ln in text.splitlines() if "outer:" in ln]
    assert len(outer) == (0 if mode == "off" else 4) and len(outer) <= 5
    assert "INFO viewfuse.test: halfway message" in text.splitlines()
    assert "[stage] done" in text.splitlines()


def test_on_mode_draws_tqdm_and_log_lines_do_not_glue(tmp_path):
    log = tmp_path / "log"
    with open(log, "wb") as fh:
        subprocess.run([sys.executable, "-c", LOOP, "on"], cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    text = log.read_bytes().decode()  # not read_text(): it would turn \r into \n
    assert "\r" in text                                   # tqdm draws when asked to
    lines = [seg for ln in text.split("\n") for seg in ln.split("\r")]
    assert "INFO viewfuse.test: halfway message" in lines  # on a line of its own
