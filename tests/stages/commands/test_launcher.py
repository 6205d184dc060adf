"""The launcher of docs/api.md (a script that imports a method of your own, then calls the CLI's
``main()``), run as a user runs it: it exits with the CLI's code, and one written without the
``__main__`` guard is refused by the first worker process that re-imports it, instead of every
worker starting the stage again and waiting forever on the lock its parent holds."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT


def run_launcher(path, *args, timeout=180):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(path), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def write(path, body: str):
    path.write_text("import sys\nfrom stages.commands.cli import main\n" + body)
    return path


@pytest.mark.parametrize("body", ['if __name__ == "__main__":\n    sys.exit(main())\n',
                                  'if __name__ == "__main__":\n    main()\n'])
def test_a_config_error_through_the_launcher_exits_2(tmp_path, body):
    launcher = write(tmp_path / "launch.py", body)
    r = run_launcher(launcher, "status", "--set", f"run.artifacts={tmp_path / 'a'}", "--set", "evaluate.bootstrap=-1")
    assert r.returncode == 2, r.stderr
    assert "evaluate.bootstrap" in r.stderr


def test_a_launcher_without_the_guard_is_refused_not_hung(tmp_path):
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("the data stage starts its worker pool only with two cores or more (data.synthetic.workers is capped)")
    launcher = write(tmp_path / "unguarded.py", "main()\n")
    art = tmp_path / "artifacts"
    r = run_launcher(launcher, "data", "--config", "configs/smoke.toml", "--set", f"run.artifacts={art}",
                     "--set", "data.synthetic.workers=2", "--set", "run.device=cpu", timeout=240)
    assert r.returncode != 0
    assert "re-imported the launcher script" in r.stderr and str(launcher) in r.stderr, r.stderr
    assert 'if __name__ == "__main__"' in r.stderr
