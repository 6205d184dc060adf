"""Shared pytest fixtures: a config pointing at a temporary artifacts folder."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

# OpenCV's decoder limits are set when the project is imported, and OpenCV reads them once, when
# it is loaded: import the project before any test module can import cv2, as the stages do.
import pipeline.infra.decoder_limits  # noqa: F401,E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = ROOT / "configs" / "synthetic.toml"

# Two cores here: keep BLAS/torch from oversubscribing when tests run.
os.environ.setdefault("OMP_NUM_THREADS", "2")

_NUMBA_CACHE: list[str] = []


PIN = "VIEWFUSE_BUILTINS_ONLY"   # pipeline.infra.registry.PIN


def _pin_registries(config) -> None:
    """Every registry holds its built-ins only (``pipeline.infra.registry.pinned``) for the whole
    session, fixtures of every scope and the interpreters tests start included (they inherit the
    environment), so a plugin installed in a contributor's venv changes no test's method, planner,
    metric, classifier or dataset list. A test that means to load entry points opts in with
    ``@pytest.mark.plugins`` (the ``registries_pinned`` fixture lifts the pin for it), and the
    helpers that start an interpreter with an outside package (tests/support/outside_package.py)
    lift it there."""
    os.environ[PIN] = "1"


@pytest.fixture(autouse=True)
def registries_pinned(request, monkeypatch):
    """Built-ins only (``_pin_registries``), unless the test is marked ``plugins``."""
    if request.node.get_closest_marker("plugins"):
        monkeypatch.delenv(PIN, raising=False)
    else:
        monkeypatch.setenv(PIN, "1")


def pytest_configure(config):
    """The fusion kernels compile once for the session, not once per process: the suite starts
    dozens (xdist workers, CLI runs, Ray workers, examples), each 10-30 s of numba compiling.
    NUMBA_CACHE_DIR (pipeline/method/kernels.py) points numba at a folder of the session's own,
    set here in the controlling process before any worker starts (they inherit it) and removed at
    the end. A user's own NUMBA_CACHE_DIR is left as it is."""
    _pin_registries(config)
    if hasattr(config, "workerinput") or os.environ.get("NUMBA_CACHE_DIR"):
        return
    _NUMBA_CACHE.append(tempfile.mkdtemp(prefix="viewfuse-tests-numba-"))
    os.environ["NUMBA_CACHE_DIR"] = _NUMBA_CACHE[0]


def pytest_unconfigure(config):
    if _NUMBA_CACHE:
        os.environ.pop("NUMBA_CACHE_DIR", None)
        shutil.rmtree(_NUMBA_CACHE.pop(), ignore_errors=True)


@pytest.fixture
def tmp_config(tmp_path):
    """Factory: load the default config with overrides, artifacts under tmp_path."""
    from pipeline.infra.config import merge, load_config

    def make(overrides: dict | None = None):
        # tests hold the report to every self-check (a layout slip fails too)
        # the stage cache off: a test that edits or removes an output expects the stage to run
        # again (tests/stages/framework/test_stage_cache.py turns it on)
        over = merge({"run": {"artifacts": str(tmp_path / "artifacts"), "stage_cache_gb": 0}, "report": {"strict": "all"}},
                     overrides or {})
        return load_config(DEFAULT_CONFIG, over)

    return make


# The longest modules (whole chains) run first. Under pytest-xdist (`make test`, --dist loadfile
# --no-loadscope-reorder: without the last flag xdist sorts modules by their number of tests and
# ignores this order) a module runs whole on one worker, and workers take modules in collection
# order: a chain taken last runs alone at the end while the other worker sits idle. The two
# workers start on the smoke run and the Ray tests; the chains that copy the smoke run's upstream
# (end to end, custom method) come after the real-data chains, when it is built, so that no worker
# waits on the other's build. Moving whole modules keeps each module's tests together (its
# module-scoped fixture still runs once).
LONGEST_FIRST = (
    "tests/stages/test_smoke_run.py", "tests/stages/test_ray.py",
    "tests/stages/test_real_category_chain.py", "tests/stages/test_real_imagery_chain.py",
    "tests/stages/test_end_to_end.py", "tests/stages/test_custom_method.py",
    "tests/stages/test_signals.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    # a node id starts with its file's path from the project root; stable sort: every other
    # module keeps its place and its order
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))
