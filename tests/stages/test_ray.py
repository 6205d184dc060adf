"""The Ray executor on a local Ray instance (2 worker CPUs, loopback only): item order, Ray's
retries, failures that name the task, and the features stage giving the same Parquet files through
Ray as in this process. Skipped when Ray is not installed, unless VIEWFUSE_REQUIRE_RAY=1 (CI).

Bounded in time: if a test hangs, faulthandler dumps every thread's stack and ends the run after
``LIMIT_S`` (per test, generous: a loaded 2-core machine runs a chain test here in 2-5 min) instead
of letting CI sit until its own limit.
"""
import faulthandler
import importlib.util
import os
import shutil
import time

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.infra.config import merge
from pipeline.infra.executor import LocalExecutor, TransientError, make_executor, task_cpus
from tests.support.tiny_world import TINY as TINY_WORLD

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

LIMIT_S = 1200
HAVE_RAY = importlib.util.find_spec("ray") is not None
if not HAVE_RAY and os.environ.get("VIEWFUSE_REQUIRE_RAY") == "1":
    raise RuntimeError("VIEWFUSE_REQUIRE_RAY=1 but Ray is not installed (pip install -e '.[ray]')")
needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="Ray not installed (pip install -e '.[ray]')")

# A tiny world (one scan, six instances in a small room, 8 turntable views per object, 72 AVD
# boxes): six targets, one ablation, dropout samples on both feature tables, and a batch size
# that does not divide the crops.
SIX = ["aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "crystal_hot_sauce",
       "honey_bunches_of_oats_honey_roasted", "mahatma_rice", "pepto_bismol"]
TINY = merge(TINY_WORLD, {
    "data": {"synthetic": {"instances": SIX, "angle_step_deg": 45, "bigbird_width": 160, "bigbird_height": 128,
                           "avd_width": 320, "avd_height": 180, "room_size_m": [2.4, 2.1], "grid_step_m": 0.45,
                           "distractors": 2, "workers": 1}},
    "classifier": {"training": {"train_images": 36, "val_images": 12, "batch_size": 12}},
    "features": {"bigbird_samples": 2, "batch_size": 7},
    "evaluate": {"track_length": 2, "bootstrap": 100,
                 "biased": {"n_loc_samples": 4},
                 "randomized": {"realizations": 4, "n_loc_samples": 4},
                 "sensitivity": {"n_loc_samples": 3}},
})


# -- task functions (module level: Ray workers import them by name) ----------------------------
def _slow_square(shared, i):
    time.sleep(shared * (5 - i % 5))          # early items finish last
    return i * i


def _seeded(shared, item):
    """Randomness from the item's identity only (a named stream, ``pipeline.infra.seeds``): the
    same on any worker, in any order."""
    from pipeline.infra import seeds
    from pipeline.infra.device import available_cores

    return float(seeds.stream(shared, "item", item).normal()), task_cpus(), available_cores()


def _flaky(folder, item):
    """Fails with TransientError on its first ``item`` attempts (counted in files), then works."""
    n = len(os.listdir(folder))
    open(os.path.join(folder, f"try{n}"), "w").close()
    if n < item:
        raise TransientError(f"flaky attempt {n}")
    return n


def _bad(shared, item):
    if item == 3:
        raise ValueError(f"bad item {item}: its box is empty")
    return item


@pytest.fixture(scope="module")
def ray_ex():
    if not HAVE_RAY:
        pytest.skip("Ray not installed")
    ex = make_executor("ray", workers=2)
    try:
        yield ex
    finally:
        ex.close()


@pytest.fixture(autouse=True)
def _watchdog():
    faulthandler.dump_traceback_later(LIMIT_S, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@needs_ray
def test_local_instance_is_loopback_only_with_two_cpus(ray_ex):
    import psutil

    assert ray_ex.node_address == "127.0.0.1"
    assert ray_ex.cpus == 2 and ray_ex.slots() == 2
    ray_ex.map(_slow_square, [0, 1], shared=0.0)               # worker processes exist
    # Every socket the instance's processes (GCS, raylet, agents, workers) listen on is loopback.
    listening = []
    for proc in psutil.Process().children(recursive=True):
        try:
            conns = proc.net_connections(kind="inet")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        listening += [(proc.name(), c.laddr.ip) for c in conns if c.status == psutil.CONN_LISTEN]
    assert len(listening) >= 3, listening
    assert all(ip in ("127.0.0.1", "::1", "::ffff:127.0.0.1") for _, ip in listening), listening


@needs_ray
def test_results_come_back_in_item_order(ray_ex):
    items = list(range(10))
    assert ray_ex.map(_slow_square, items, shared=0.05, desc="squares") == [i * i for i in items]
    # imap reads a generator lazily and keeps the order with a window smaller than the items.
    assert list(ray_ex.imap(_slow_square, (i for i in items), shared=0.01, window=3)) == [i * i for i in items]
    assert ray_ex.map(_slow_square, [], shared=0.0) == []


@needs_ray
def test_calls_are_recorded_for_the_bench(ray_ex):
    from pipeline.infra import executor as ex
    ray_ex.map(_slow_square, [0, 1, 2, 3], shared=0.02, desc="timed")
    rec = ex.STATS[-1]
    assert (rec["executor"], rec["desc"], rec["tasks"], rec["slots"]) == ("ray", "timed", 4, 2)
    # Tasks sleep 0.1, 0.08, 0.06, 0.04 s: measured inside the workers, the map call takes longer.
    assert 0.28 <= rec["task_s"] < rec["wall_s"] * 2 and rec["task_max_s"] >= 0.1
    LocalExecutor().map(_slow_square, [0, 1], shared=0.02, desc="here")
    assert ex.STATS[-1]["executor"] == "local" and ex.STATS[-1]["tasks"] == 2


@needs_ray
def test_seeded_tasks_give_the_local_numbers(ray_ex):
    items = list(range(12))
    remote = ray_ex.map(_seeded, items, shared=7)
    local = LocalExecutor().map(_seeded, items, shared=7)
    assert [r[0] for r in remote] == [r[0] for r in local]
    # Inside a Ray task: one CPU, and thread pools (the fusion engine's) size to it.
    assert {r[1:] for r in remote} == {(1, 1)} and {r[1] for r in local} == {0}


@needs_ray
def test_transient_errors_are_retried(ray_ex, tmp_path):
    folder = tmp_path / "tries"
    folder.mkdir()
    assert ray_ex.map(_flaky, [2], shared=str(folder)) == [2]       # third attempt works
    assert len(os.listdir(folder)) == 3


@needs_ray
def test_a_task_that_keeps_failing_stops_with_its_own_message(ray_ex, tmp_path):
    folder = tmp_path / "tries"
    folder.mkdir()
    with pytest.raises(RuntimeError, match=r"flaky: task 1 of 1 \(99\) failed \(after 3 retries\): "
                                           r"TransientError: flaky attempt 3"):
        ray_ex.map(_flaky, [99], shared=str(folder), desc="flaky")
    assert len(os.listdir(folder)) == 1 + ray_ex.retries
    # A plain error is not retried: it names the task and keeps the task's message.
    with pytest.raises(RuntimeError, match=r"cells: task 4 of 5 \(3\) failed: ValueError: bad item 3: its box is empty"):
        ray_ex.map(_bad, range(5), desc="cells")


# -- the features and evaluate stages through Ray ---------------------------------------------
@pytest.fixture(scope="module")
def upstream(tmp_path_factory):
    """data + classifier once, copied into a folder per executor."""
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    base = tmp_path_factory.mktemp("ray") / "base"
    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {"artifacts": str(base), "device": "cpu"}}))
    ensure(cfg, "classifier", device="cpu")
    ensure(cfg, "data", device="cpu")
    return base


def _run(upstream, name, stage, executor, reuse=None, stages=()):
    """Run ``stage`` in artifacts folder ``name`` (a copy of ``upstream``); ``stages`` of run
    ``reuse`` that do not go through the executor are copied in first instead of run again."""
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    art = upstream.parent / name
    if not art.exists():
        shutil.copytree(upstream, art)
    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {
        "artifacts": str(art), "device": "cpu", "executor": executor, "ray_workers": 2}}))
    for s in stages:
        if not cfg.stage_dir(s).exists():
            shutil.copytree(reuse.stage_dir(s), cfg.stage_dir(s))
    ensure(cfg, stage, device="cpu")
    return cfg


def assert_same_parquet(a, b):
    ta, tb = pq.read_table(a), pq.read_table(b)
    assert ta.schema.metadata == tb.schema.metadata, a.name
    assert ta.schema == tb.schema and ta.num_rows == tb.num_rows and ta.num_rows > 0, a.name
    assert ta.equals(tb), f"{a.name}: values differ"


@needs_ray
def test_features_through_ray_equal_the_local_run(ray_ex, upstream):
    from stages.framework.runner import read_manifest

    local = _run(upstream, "local", "features", "local")
    ray_ = _run(upstream, "ray", "features", "ray")
    for name in ("bigbird.parquet", "avd.parquet"):
        assert_same_parquet(local.stage_dir("features") / name, ray_.stage_dir("features") / name)
    assert read_manifest(ray_, "features")["extra"]["executor"] == "ray"
    # Batches of 7 do not divide the crops: the last, short batch is scored too.
    n = read_manifest(ray_, "features")["extra"]["avd_crops"]
    assert n % 7 and len(pq.read_table(ray_.stage_dir("features") / "avd.parquet")) == n * 4


@needs_ray
def test_evaluate_through_ray_equals_the_local_run(ray_ex, upstream):
    import json

    from pipeline.infra import executor as ex
    local = _run(upstream, "local", "evaluate", "local")
    del ex.STATS[:]
    # the models stage runs in-process whatever the executor: the local run's fits, not a refit
    ray_ = _run(upstream, "ray", "evaluate", "ray", reuse=local, stages=("models",))
    cells = [r for r in ex.STATS if r["executor"] == "ray" and r["desc"] == "evaluate: cells"]
    assert cells and cells[0]["tasks"] >= 2 * 2          # the grid really ran as Ray tasks
    # and so did the planning episodes (their random draws: sampled poses, the information gain's)
    assert [r for r in ex.STATS if r["executor"] == "ray" and r["desc"] == "evaluate: planning" and r["tasks"] > 0]
    a, b = local.stage_dir("evaluate"), ray_.stage_dir("evaluate")
    names = sorted(p.name for p in a.iterdir() if p.suffix in (".parquet", ".json", ".npz"))
    assert names == sorted(p.name for p in b.iterdir() if p.suffix in (".parquet", ".json", ".npz"))
    assert {"results.parquet", "planning.parquet", "summary.json"} <= set(names)
    for name in names:
        if name.endswith(".parquet"):
            assert_same_parquet(a / name, b / name)
        elif name.endswith(".npz"):
            with np.load(a / name) as x, np.load(b / name) as y:
                assert sorted(x.files) == sorted(y.files), name
                for k in x.files:
                    np.testing.assert_array_equal(x[k], y[k], err_msg=f"{name}: {k}")
        elif name != "manifest.json":
            ja, jb = json.loads((a / name).read_text()), json.loads((b / name).read_text())
            for j in (ja, jb):
                j.pop("timings_s", None)
            assert ja == jb, name


def test_executor_flag_overrides_the_config():
    import stages.commands.cli as cli
    from tests.conftest import DEFAULT_CONFIG

    def executor(*argv):
        return cli._load(cli.build_parser().parse_args([*argv, "--config", str(DEFAULT_CONFIG)])).run.executor

    assert executor("evaluate", "--executor", "ray") == "ray"
    assert executor("features") == "local"
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["report", "--executor", "dask"])


def test_scoring_goes_to_cluster_gpus_unless_the_device_is_cpu(upstream):
    """The features stage's choice for Ray (no GPU here: a stand-in executor reports them)."""
    from types import SimpleNamespace

    from pipeline.scoring.crops import CropPolicy
    from pipeline.infra.config import load_config
    from stages.features import prepare_scoring
    from tests.conftest import DEFAULT_CONFIG

    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {"artifacts": str(upstream)}}))
    policy = CropPolicy.from_config(cfg)

    def choose(request, gpus):
        ctx = SimpleNamespace(device_request=request, input=cfg.stage_dir)
        return prepare_scoring(ctx, SimpleNamespace(name="ray", gpus=gpus), policy)

    sm, card, gpu, _ = choose("auto", 2)
    assert (sm.device, gpu) == ("cuda", True) and sm.key.endswith("@cuda")
    assert sm.weights is not None and sm.num_classes == card["num_classes"] == 12
    assert all(isinstance(v, np.ndarray) for v in sm.weights.values())   # plain arrays, no pickled code
    sm, _, gpu, _ = choose("cpu", 2)
    assert (sm.device, gpu) == ("cpu", False)
    sm, _, gpu, _ = choose("auto", 0)
    assert (sm.device, gpu) == ("cpu", False)
    with pytest.raises(RuntimeError, match="run.device = 'cuda'.*no GPU"):
        choose("cuda", 0)
