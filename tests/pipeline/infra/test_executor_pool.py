"""The local executor with forked worker processes (``pipeline.infra.executor_pool.LocalPool``):
results in item order and equal to the in-process executor's, the first task run before the fork,
inherited items never pickled (their arrays keep this process's memory layout), the pool reused
for the same payload, each task told its share of the cores, and a task's error raised as itself."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from pipeline.infra.executor import LocalExecutor
from pipeline.infra.executor_pool import LocalPool
from pipeline.infra.workers import can_fork

pytestmark = pytest.mark.skipif(not can_fork(), reason="worker processes are forked")


def _reduce(shared, item):
    """A reduction over an array view: what the evaluate cells compute on their dropout samples."""
    time.sleep(0.02 * (item["i"] % 3 == 1))      # later items finish first now and then
    x = item["view"]
    return {"i": item["i"], "var": x.var(axis=-2) * shared, "pid": os.getpid(),
            "strides": x.strides, "contiguous": x.flags.c_contiguous}


def _task_cpus(shared, item):
    from pipeline.infra.device import task_cpus
    return os.getpid(), task_cpus()


def _fail(shared, item):
    if item == 5:
        raise ValueError(f"bad item {item}: its box is empty")
    return item


def _items(n=23):
    rng = np.random.default_rng(0)
    base = rng.normal(size=(n, 5, 9, 7, 4))
    # views with a step: not contiguous, as the cells' broadcast and sliced dropout arrays are
    return [{"i": i, "view": base[i, :, ::2]} for i in range(n)]


def test_same_results_in_item_order_as_in_this_process():
    items = _items()
    serial = list(LocalExecutor().imap(_reduce, items, shared=2.0))
    with LocalPool(2) as pool:
        pool.inherit(items)
        forked = list(pool.imap(_reduce, items, shared=2.0, desc="t"))
        again = list(pool.imap(_reduce, items, shared=2.0))     # the same pool, warm
    assert [r["i"] for r in forked] == list(range(len(items)))
    for a, b, c in zip(serial, forked, again):
        assert np.array_equal(a["var"], b["var"]) and np.array_equal(a["var"], c["var"])
        # inherited: the worker computed on the parent's own view, not a pickled (contiguous) copy
        assert b["strides"] == a["strides"] and not b["contiguous"]
    parent = os.getpid()
    # the first task ran here, before the fork; the rest in the workers; the second call reused them
    assert forked[0]["pid"] == parent and {r["pid"] for r in forked[1:]} - {parent}
    assert parent not in {r["pid"] for r in again}
    assert {r["pid"] for r in again} <= {r["pid"] for r in forked[1:]}


def test_items_not_inherited_travel_pickled_and_still_come_back_in_order():
    items = _items(7)
    serial = [r["var"] for r in LocalExecutor().imap(_reduce, items, shared=1.0)]
    with LocalPool(2) as pool:
        out = list(pool.imap(_reduce, iter(items), shared=1.0))
    assert [r["i"] for r in out] == list(range(7))
    assert all(np.allclose(a, r["var"], rtol=0, atol=1e-12) for a, r in zip(serial, out))


def test_each_worker_task_is_told_its_share_of_the_cores():
    from pipeline.infra.device import available_cores

    with LocalPool(2) as pool:
        out = pool.map(_task_cpus, list(range(6)))
    workers = [c for pid, c in out if pid != os.getpid()]
    assert workers and set(workers) == {max(1, available_cores() // 2)}


def test_a_task_error_is_raised_as_itself_and_the_pool_is_closed():
    pool = LocalPool(2)
    items = list(range(12))
    pool.inherit(items)
    with pytest.raises(ValueError, match="bad item 5: its box is empty"):
        list(pool.imap(_fail, items))
    pool.close()
    assert pool._pool._pool is None


def test_one_process_is_the_in_process_route():
    with LocalPool(1) as pool:
        out = pool.map(_task_cpus, [0, 1, 2])
    assert {pid for pid, _ in out} == {os.getpid()}
