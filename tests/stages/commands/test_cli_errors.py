"""One error boundary in the CLI: every expected failure ends in one line naming the file or key,
exit 2 for a config problem and 1 at run time; ``--debug`` adds the traceback."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

import stages.framework.runner as runner
from stages.commands.cli import main
from tests.support import stage_fakes

ROOT = Path(__file__).resolve().parents[3]


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("run folder:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def failing_stage(monkeypatch, exc: BaseException) -> list[str]:
    def fail(ctx):
        raise exc
    return stage_fakes.install(monkeypatch, {"a": ()}, {"a": fail})


@pytest.mark.parametrize("code, words", [
    (errno.ENOSPC, "no space left on the device (the disk is full)"),
    (errno.EROFS, "the file system is read-only"),
    (errno.EACCES, "permission denied"),
])
def test_os_errors_are_one_line_with_the_errno_explained(tmp_path, monkeypatch, capsys, code, words):
    target = tmp_path / "artifacts" / "synthetic" / ".a.tmp" / "big.bin"
    failing_stage(monkeypatch, OSError(code, os.strerror(code), str(target)))
    assert main(["a", "--set", f"run.artifacts={tmp_path / 'artifacts'}"]) == 1
    line = one_line(capsys.readouterr().err)
    assert str(target) in line and words in line and errno.errorcode[code] in line
    assert not (tmp_path / "artifacts" / "synthetic" / ".a.tmp").exists()  # the temporary output is gone


def test_debug_shows_the_traceback(tmp_path, monkeypatch, capsys):
    failing_stage(monkeypatch, OSError(errno.ENOSPC, "No space left on device"))
    assert main(["a", "--debug", "--set", f"run.artifacts={tmp_path}"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "no space left" in err.splitlines()[-1]


def test_an_unexpected_exception_is_one_line_with_a_hint(tmp_path, monkeypatch, capsys):
    failing_stage(monkeypatch, AttributeError("'list' object has no attribute 'get'"))
    assert main(["a", "--set", f"run.artifacts={tmp_path}"]) == 1
    line = one_line(capsys.readouterr().err)
    assert "AttributeError: 'list' object has no attribute 'get'" in line and "--debug" in line


def test_a_config_error_deep_in_a_stage_exits_2(tmp_path, monkeypatch, capsys):
    from pipeline.infra.config import ConfigError
    failing_stage(monkeypatch, ConfigError("x.toml: 'evaluate.ablations' entry 'models.n_components=0' ..."))
    assert main(["a", "--set", f"run.artifacts={tmp_path}"]) == 2
    assert "config error" in one_line(capsys.readouterr().err)


@pytest.mark.parametrize("encoding, hint", [("latin-1", "not UTF-8"), ("utf-16", "UTF-16")])
def test_a_config_file_that_is_not_utf8_is_named(tmp_path, capsys, encoding, hint):
    cfg = tmp_path / "bad.toml"
    cfg.write_bytes('[report]\ntitle = "caf\u00e9 r\u00e9sum\u00e9"\n'.encode(encoding))
    assert main(["status", "--config", str(cfg)]) == 2
    line = one_line(capsys.readouterr().err)
    assert str(cfg) in line and hint in line


def test_a_nul_byte_in_the_run_name_is_a_config_error_naming_the_key(tmp_path, capsys):
    cfg = tmp_path / "nul.toml"
    cfg.write_text('[run]\nname = "a\\u0000b"\n')
    for cmd in ("status", "data"):
        assert main([cmd, "--config", str(cfg)]) == 2
        line = one_line(capsys.readouterr().err)
        assert "'run.name'" in line and str(cfg) in line


def test_an_unknown_or_unfit_classifier_is_a_config_error_before_any_stage(tmp_path, capsys):
    cfg = tmp_path / "arch.toml"
    for text, words in (('[classifier]\narch = "resnet"\n', "'classifier.arch': unknown classifier architecture 'resnet'"),
                        ('[classifier]\narch = "torchvision:resnet18"\n', "'torchvision:resnet18' trains nothing")):
        cfg.write_text(text)
        assert main(["status", "--config", str(cfg)]) == 2
        line = one_line(capsys.readouterr().err)
        assert words in line and str(cfg) in line


def test_status_exits_1_when_a_stage_state_is_unknown(tmp_path, monkeypatch, capsys):
    def broken(cfg, name, memo=None):
        raise OSError(errno.EACCES, "Permission denied", "/x/manifest.json")
    monkeypatch.setattr(runner, "plan", broken)
    assert main(["status", "--set", f"run.artifacts={tmp_path}"]) == 1
    out = capsys.readouterr().out
    assert "unknown: /x/manifest.json: permission denied (EACCES)" in out


def test_status_into_a_closed_pipe_is_quiet(tmp_path):
    # The reader is gone before viewfuse writes (as with '| head -1' on a long listing).
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run(f"'{sys.executable}' -m stages.commands.cli status --set run.artifacts='{tmp_path}' | true",
                       shell=True, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr
