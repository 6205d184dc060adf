"""The command line: status, --version, per-stage help, and flags validated like config values."""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def test_threads_flag_is_validated_like_the_config_value(capsys):
    from stages.commands.cli import main

    assert main(["status", "--config", str(ROOT / "configs" / "synthetic.toml")]) == 0
    capsys.readouterr()
    assert main(["data", "--threads", "-1"]) == 2
    assert "'run.threads' = -1 is below the minimum 0" in capsys.readouterr().err


def test_cli_status_version_and_stage_help(tmp_path, capsys):
    from stages.commands.cli import main

    assert main(["status", "--set", f"run.artifacts={tmp_path}"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines] == ["data", "classifier", "features", "models", "evaluate",
                                               "report", "simulate"]
    assert all(ln.split(None, 1)[1] == "missing" for ln in lines)
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("viewfuse ")
    with pytest.raises(SystemExit):
        main(["features", "--help"])
    out = capsys.readouterr().out
    assert "features.n_samples = 10 in [1, 1000]: N_s dropout samples per AVD crop" in out
    assert "models.restarts" not in out and "--progress {auto,on,off}" in out
