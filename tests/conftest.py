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


# The longest modules (whole chains) run first. Under pytest-xdist (`make test`, --dist loadfile) a
# module runs whole on one worker, and workers take modules in collection order: a chain collected
# last ran alone at the end while the other worker sat idle. Moving whole modules keeps each
# module's tests together (its module-scoped fixture still runs once).
LONGEST_FIRST = (
    "tests/stages/test_smoke_run.py", "tests/stages/test_end_to_end.py", "tests/stages/test_ray.py",
    "tests/stages/test_real_category_chain.py", "tests/stages/test_real_imagery_chain.py",
    "tests/pipeline/planning/test_population.py", "tests/stages/test_custom_method.py",
    "tests/stages/test_signals.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    # a node id starts with its file's path from the project root; stable sort: every other
    # module keeps its place and its order
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
