"""Shared pytest fixtures: a config pointing at a temporary artifacts folder."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = ROOT / "configs" / "synthetic.toml"

# Two cores here: keep BLAS/torch from oversubscribing when tests run.
os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture
def tmp_config(tmp_path):
    """Factory: load the default config with overrides, artifacts under tmp_path."""
    from pipeline.infra.config import merge, load_config

    def make(overrides: dict | None = None):
        # tests hold the report to every self-check (a layout slip fails too)
        over = merge({"run": {"artifacts": str(tmp_path / "artifacts")}, "report": {"strict": "all"}},
                     overrides or {})
        return load_config(DEFAULT_CONFIG, over)

    return make
