"""The tiny world's upstream stages (data → classifier → features → models), built once per test
session and copied into each chain test's own artifacts folder.

The end-to-end and custom-method chain tests need the same finished upstream; each built it anew,
a few minutes apiece (the custom-method test's config differs in evaluate.ablations, so its copy
refits the models stage and reuses the rest). Under pytest-xdist the workers share one build folder beside
their own temporary roots: the framework's stage locks let the first worker build a stage while
the others wait and then find it up to date, which is the behaviour a user running two commands on
one run folder gets. Each test then works on a copy, so no test sees another's downstream output."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from tests.support.tiny_world import TINY

UPSTREAM = "models"   # the last stage built in the shared folder


def _shared_root(tmp_path_factory) -> Path:
    base = tmp_path_factory.getbasetemp()
    # xdist gives each worker <root>/popen-gwN; the parent is common to the session's workers
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def tiny_upstream(tmp_path_factory) -> Path:
    """The artifacts folder holding the tiny run with every stage up to ``UPSTREAM`` done."""
    from pipeline.infra.config import load_config, merge
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    art = _shared_root(tmp_path_factory) / "tiny-upstream" / "artifacts"
    cfg = load_config(DEFAULT_CONFIG, merge({"run": {"artifacts": str(art), "device": "cpu"}}, TINY))
    ensure(cfg, UPSTREAM, device="cpu")
    return art


def copy_upstream(src: Path, dst: Path) -> Path:
    """Copy a finished artifacts folder, leaving out lock files another worker may hold or delete."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(".*.lock", ".*.workers"))
    return dst
