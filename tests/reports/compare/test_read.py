"""``viewfuse compare`` on folders it did not write: regular files only, size caps, nesting and
structure checked with errors naming the run, the file and the field, unreadable manifests noted,
control characters escaped in the terminal table."""
from __future__ import annotations

import json
import os
import signal

import pytest

from pipeline.infra.nesting import depth
from reports.compare.page import render_text
from reports.compare.read import MAX_DEPTH, MAX_SUMMARY_BYTES, printable
from reports.compare.runs import CompareError, compare
from stages.commands.cli import main
from tests.stages.commands.test_compare import write_run


def _summary(run):
    return run / "evaluate" / "summary.json"


def _edit_summary(run, change):
    s = json.loads(_summary(run).read_text())
    change(s["population"])
    _summary(run).write_text(json.dumps(s))


@pytest.fixture
def alarm():
    """Fail instead of hanging when a read blocks (the FIFO case)."""
    old = signal.signal(signal.SIGALRM, lambda *_: pytest.fail("compare blocked reading the folder"))
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def test_a_summary_symlinked_to_dev_zero_is_refused_before_reading(tmp_path):
    run = write_run(tmp_path / "a")
    _summary(run).unlink()
    os.symlink("/dev/zero", _summary(run))
    with pytest.raises(CompareError, match=r"run a: .*summary.json: .*character device.*/dev/zero.*not a regular file"):
        compare([run])


def test_a_summary_that_is_a_fifo_is_refused_without_blocking(tmp_path, alarm):
    run = write_run(tmp_path / "a")
    _summary(run).unlink()
    os.mkfifo(_summary(run))
    with pytest.raises(CompareError, match=r"run a: .*summary.json: .*FIFO"):
        compare([run])


def test_a_summary_above_the_cap_is_refused_by_its_size(tmp_path):
    run = write_run(tmp_path / "a")
    with open(_summary(run), "r+b") as f:
        f.truncate(MAX_SUMMARY_BYTES + 1)  # sparse: no disk used
    with pytest.raises(CompareError, match=r"run a: .*summary.json: .*MiB, above the 64 MiB"):
        compare([run])


def test_a_summary_nested_100000_deep_is_a_named_error(tmp_path):
    run = write_run(tmp_path / "a")
    _summary(run).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CompareError, match=rf"run a: .*summary.json: .*nested deeper than {MAX_DEPTH}"):
        compare([run])
    deep = {"population": {"pooled": {}}}
    d = deep
    for _ in range(MAX_DEPTH + 1):   # deep enough to refuse, shallow enough for the parser
        d["x"] = {}
        d = d["x"]
    _summary(run).write_text(json.dumps(deep))
    with pytest.raises(CompareError, match=r"nested deeper"):
        compare([run])


def test_depth_counts_levels_without_recursion():
    assert depth(1) == 0 and depth([]) == 1 and depth({"a": [1, {"b": 2}]}) == 3
    v = []
    for _ in range(50_000):
        v = [v]
    assert depth(v) == 50_001


@pytest.mark.parametrize("change, field, found", [
    (lambda p: p["verdict_table"][1].pop("comparison"), r"population\.verdict_table\[1\]: the field 'comparison'", ""),
    (lambda p: p.__setitem__("verdict_table", [1, 2]), r"population\.verdict_table\[0\]: expected an object",
     "a number 1"),
    (lambda p: p.__setitem__("records", [{"metric": "correct_final", "outcome": "better"}]),
     r"population\.records\[0\]: the field 'comparison'", ""),
    (lambda p: p["pooled"].__setitem__("with_uncertainty", 5), r"population\.pooled\.with_uncertainty: expected an "
     r"object", "a number 5"),
    (lambda p: p["pooled"]["model_based"]["correct_final"].__setitem__("ci_low", "0.5"),
     r"population\.pooled\.model_based\.correct_final\.ci_low: expected a number or null", 'a string "0.5"'),
])
def test_a_summary_of_the_wrong_structure_names_the_run_the_file_and_the_field(tmp_path, change, field, found):
    run = write_run(tmp_path / "a")
    _edit_summary(run, change)
    with pytest.raises(CompareError, match=rf"run a: .*evaluate/summary.json: {field}") as e:
        compare([run])
    assert found in str(e.value)


def test_the_cli_reports_a_bad_summary_as_an_error_not_a_crash(tmp_path, capsys):
    run = write_run(tmp_path / "a")
    _edit_summary(run, lambda p: p["pooled"].__setitem__("with_uncertainty", 5))
    assert main(["compare", str(run)]) == 1
    err = capsys.readouterr().err
    assert "error: run a:" in err and "population.pooled.with_uncertainty" in err and "internal error" not in err


@pytest.mark.parametrize("manifest, why", [
    ({"stage": "models", "parts": {"sections": [1, 2]}}, "parts.sections: expected an object, found a list [1, 2]"),
    ([1], "the top level: expected an object, found a list [1]"),
])
def test_an_unreadable_manifest_is_noted_with_its_field_and_its_stage_config_left_out(tmp_path, manifest, why):
    a, b = write_run(tmp_path / "a"), write_run(tmp_path / "b")
    (b / "models" / "manifest.json").write_text(json.dumps(manifest))
    c = compare([a, b])
    notes = [n for n in c.notes if n.startswith("b: ")]
    assert any(f"models/manifest.json is unreadable ({why})" in n and "models stage's config is not compared" in n
               for n in notes), notes
    # the models stage's keys are absent in b (so they differ), the others still compared
    assert c.config["models.component_rule"] == ["top_mean", "—"]
    assert "classifier.epochs" not in c.config
    assert "unreadable" in render_text(c)


def test_a_manifest_that_is_a_fifo_is_noted_without_blocking(tmp_path, alarm):
    a = write_run(tmp_path / "a")
    (a / "data" / "manifest.json").unlink()
    os.mkfifo(a / "data" / "manifest.json")
    c = compare([a])
    assert any("data/manifest.json is unreadable" in n and "FIFO" in n for n in c.notes), c.notes


def test_terminal_escapes_in_config_values_and_names_are_shown_escaped(tmp_path):
    a = write_run(tmp_path / "a")
    b = write_run(tmp_path / "b\x1b[2J")
    m = b / "models" / "manifest.json"
    evil = "\x1b]0;owned\x07\x1b[2J\u202etop"
    m.write_text(json.dumps({"parts": {"sections": {"models": {"models": {"component_rule": evil}}}}}))
    text = render_text(compare([a, b]))
    assert "\x1b" not in text and "\x07" not in text and "\u202e" not in text
    assert r"\x1b]0;owned\x07\x1b[2J\u202etop" in text and r"b\x1b[2J" in text


def test_printable_keeps_ordinary_text_and_escapes_only_controls():
    assert printable("σ = 0.1 m · ok") == "σ = 0.1 m · ok"
    assert printable("a\tb\nc\x9b") == r"a\tb\nc\x9b"
