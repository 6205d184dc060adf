"""A package outside the repository, written by a test: one module and a ``.dist-info`` folder
whose ``entry_points.txt`` names it in viewfuse's entry-point groups, in a folder that a
subprocess gets on its PYTHONPATH (``importlib.metadata`` finds the dist-info there as it finds an
installed one)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def write_package(where: Path, name: str, module_source: str, entry_points: dict[str, dict[str, str]]) -> Path:
    """``where/<name>.py`` and ``where/<name>-0.1.dist-info/{METADATA, entry_points.txt}``;
    ``entry_points``: group -> {entry name: value}. Returns ``where``."""
    where.mkdir(parents=True, exist_ok=True)
    (where / f"{name}.py").write_text(module_source)
    info = where / f"{name}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n" for group, eps in entry_points.items()))
    return where


def unpinned(env: dict) -> dict:
    """``env`` without the test session's pin of the registries to their built-ins
    (tests/conftest.py): an interpreter started with an outside package loads its entry points."""
    return {k: v for k, v in env.items() if k != "VIEWFUSE_BUILTINS_ONLY"}


def run_with(site: Path | None, code: str, cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    """``python -c code`` in a fresh interpreter with ``site`` (if any) ahead of the repository on
    PYTHONPATH, its registries loading the entry points installed there (``unpinned``)."""
    path = os.pathsep.join(str(p) for p in (site, ROOT) if p is not None)
    env = unpinned({**os.environ, "PYTHONPATH": path, "OMP_NUM_THREADS": "1"})
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
