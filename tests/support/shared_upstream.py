"""The smoke run (configs/smoke.toml), built once per test session in a folder the test workers
share, and its upstream stages (data → classifier → features → models) copied into the chain
tests' own artifacts folders.

The smoke test runs the main job through the CLI there; the end-to-end and custom-method chain
tests need the same finished upstream (their configs differ downstream of it). Each built it anew,
a few minutes apiece. Under pytest-xdist the workers share one folder beside their own temporary
roots: the framework's stage locks let the first process build a stage while the others wait and
then find it up to date, the behaviour a user running two commands on one run folder gets. Each
chain test then works on a copy of the upstream stages only, so no test sees another's downstream
output, and a copy taken while the smoke CLI still writes its evaluate stage takes none of it."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from tests.conftest import ROOT

SMOKE = ROOT / "configs" / "smoke.toml"
# Built in the shared folder and copied. A chain test's config is the smoke config with its own
# evaluate/report/simulate settings on top, so the copied stages' keys match and they are up to date.
UPSTREAM = ("data", "classifier", "features", "models")
DEVICE = "cpu"   # one device for the CLI and the in-process runs: stage keys name it


def _shared_root(tmp_path_factory) -> Path:
    base = tmp_path_factory.getbasetemp()
    # xdist gives each worker <root>/popen-gwN; the parent is common to the session's workers
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def smoke_artifacts(tmp_path_factory) -> Path:
    """The session's shared artifacts folder of the smoke run (it may not be built yet)."""
    return _shared_root(tmp_path_factory) / "smoke-shared" / "artifacts"


def smoke_config(artifacts: Path, overrides: dict | None = None):
    from pipeline.infra.config import load_config, merge
    return load_config(SMOKE, merge({"run": {"artifacts": str(artifacts), "device": DEVICE}}, overrides or {}))


def smoke_upstream(tmp_path_factory, upto: str = UPSTREAM[-1]) -> Path:
    """The shared artifacts folder with the smoke run's upstream stages done up to ``upto`` (built
    here, or by the process that got there first)."""
    from stages.framework.runner import ensure

    art = smoke_artifacts(tmp_path_factory)
    ensure(smoke_config(art), upto, device=DEVICE)
    return art


def copy_upstream(src: Path, dst: Path, stages: tuple[str, ...] = UPSTREAM) -> Path:
    """Copy the finished upstream stage folders (``stages``) of every run in artifacts folder ``src`` to ``dst``."""
    for run in (p for p in src.iterdir() if p.is_dir() and not p.name.startswith(".")):   # not .stage-cache
        for stage in stages:
            shutil.copytree(run / stage, dst / run.name / stage)
    return dst


# A small evaluate on the smoke upstream: one track per target, one randomized setting, no planning.
SMALL_EVALUATE = {"evaluate.ablations": "[]", "evaluate.attribution": "false", "evaluate.tracks_per_target": "1",
                  "evaluate.bootstrap": "100", "evaluate.randomized.sigmas_m": "[0.3]", "plan.enabled": "false"}


def run_evaluate(artifacts: Path, launcher: list[str], site: Path, sets: dict[str, str] | None = None):
    """``<launcher> evaluate`` on the smoke config with ``SMALL_EVALUATE`` (and ``sets`` over it) in
    a fresh interpreter, with ``site`` (an outside package, tests/support/outside_package.py) on its
    PYTHONPATH."""
    import subprocess
    import sys

    cmd = [sys.executable, *launcher, "evaluate", "--config", str(SMOKE), "--device", DEVICE, "--progress", "off"]
    for k, v in {"run.artifacts": str(artifacts), **SMALL_EVALUATE, **(sets or {})}.items():
        cmd += ["--set", f"{k}={v}"]
    from tests.support.outside_package import unpinned

    env = unpinned({**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(site)]),
                    "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")})
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1500)
