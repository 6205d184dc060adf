"""A local Ray instance's workers see the entry points the driver sees: the executor hands them the
driver's PYTHONPATH (which holds an outside package's dist-info), and a worker, a fresh
interpreter, loads the registries on first use. Ray itself is stood in for (its ``init`` records
what it was given), so this runs without Ray; tests/stages/test_ray.py runs the real one."""
from __future__ import annotations

import os
import subprocess
import sys
import types

import pytest

from tests.support.outside_kinds import ENTRY_POINTS, MODULE, PACKAGE
from tests.support.outside_package import unpinned, write_package


def _fake_ray(monkeypatch) -> dict:
    seen: dict = {}
    ray = types.ModuleType("ray")
    ray.is_initialized = lambda: False
    ray.init = lambda **kw: seen.update(kw)
    ray.cluster_resources = lambda: {"CPU": 2}
    ray.remote = lambda fn: fn
    ray.util = types.SimpleNamespace(get_node_ip_address=lambda: "127.0.0.1")
    private = types.ModuleType("ray._private")
    private.ray_constants = types.SimpleNamespace(ENABLE_RAY_CLUSTER=True)
    ray._private = private
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.setitem(sys.modules, "ray._private", private)
    return seen


# What a worker does with a task: unpack it and look the run's entries up by name (a first use,
# so the registries load the built-ins and the entry points in that process).
WORKER = '''
from pipeline.infra.executor_ray import _run_task
from pipeline.evaluation.metrics.spec import METRICS
from pipeline.method.registry import outside_fingerprint
from pipeline.planning.planners import PLANNERS
from pipeline.scoring.classifiers import names

def task(shared, item):
    return [item in names(), item in PLANNERS or item in METRICS, outside_fingerprint().split("=")[0]]

out, _ = _run_task(task, None, "outside_tiny", 1)
out2, _ = _run_task(task, None, "outside_first", 1)
print("WORKER", out[0], out2[1], "p_truth_squared_final" in METRICS, out[2])
'''


@pytest.mark.plugins
def test_a_local_ray_worker_gets_the_drivers_path_and_loads_the_outside_entry_points(monkeypatch, tmp_path):
    from pipeline.infra.executor_ray import RayExecutor, code_root

    site = write_package(tmp_path / "site", PACKAGE, MODULE, ENTRY_POINTS)
    monkeypatch.setenv("PYTHONPATH", str(site))
    seen = _fake_ray(monkeypatch)
    RayExecutor(workers=2)
    path = seen["runtime_env"]["env_vars"]["PYTHONPATH"]
    assert path.split(os.pathsep) == [str(code_root()), str(site)]   # the checkout first, then the driver's path
    # a worker: a fresh interpreter with that environment
    r = subprocess.run([sys.executable, "-c", WORKER], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                       env=unpinned({**os.environ, "PYTHONPATH": path, "OMP_NUM_THREADS": "1"}))
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == ["WORKER", "True", "True", "True", "outside_vote"]
