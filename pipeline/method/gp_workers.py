"""The batched GP fit's stacked evaluations shared out over forked worker processes
(docs/design.md §5, "Fitting every GP at once").

The lock step stays in this process, run for run and round for round as in one process: only
each round's stacked evaluations (``gp_batch.Stack.blocks``) are cut into parts, one per worker,
this process computing the first and forked workers (holding the stack since the fork) the
others. A fit's objective and gradient come from its own rows of the stack alone, but numpy's
``einsum`` sums a lone matrix (a stack of one) in another order than a row of a larger stack (1
ulp), and a 1-ulp gradient moves an L-BFGS-B path: so a block is cut only into parts of at least
two rows, and a block of fewer than four rows stays whole. Every fit then gets the same bits as in
one process, whatever the worker count (tests/pipeline/method/test_gp_workers.py). Where processes
cannot fork, or one worker is asked for, the stack is evaluated in this process.

The worker count is set around a stage's fits with ``fit_workers(n, budget)`` (the models stage:
its ``run.threads``, else the cores free now, capped by the memory budget); outside it, one.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

import numpy as np
from pipeline.infra.workers import inherited
from pipeline.infra.workers import can_fork, forked_pool
from pipeline.infra.budget import AUTO_SHARE, cap_workers, machine_memory

_WORKERS = [1, 0]   # worker count, memory budget in bytes (0: AUTO_SHARE of the machine's)
# bytes a worker holds beyond what it shares with this process: the stacked (BLOCK, u, u) arrays
# of ``objective`` (about a dozen at once) and the interpreter's own pages it writes to
_PER_MATRIX_COPIES = 12
_PROCESS_BYTES = 64 << 20


@contextlib.contextmanager
def fit_workers(n: int, memory_budget: int = 0) -> Iterator[int]:
    """Within the block, batched GP fits share their evaluations out over at most ``n`` processes
    (this one included), as many as ``memory_budget`` bytes (the run's,
    ``pipeline.infra.budget.budget``; 0: ``AUTO_SHARE`` of the machine's) hold beside this one."""
    old = list(_WORKERS)
    _WORKERS[:] = [max(1, int(n)), int(memory_budget)]
    try:
        yield _WORKERS[0]
    finally:
        _WORKERS[:] = old


def current_workers() -> int:
    return _WORKERS[0]


def worker_bytes(largest_u: int, block: int) -> float:
    """About what one fit worker holds: ``_PER_MATRIX_COPIES`` stacks of ``block`` (u, u) matrices."""
    return _PROCESS_BYTES + _PER_MATRIX_COPIES * 8.0 * block * largest_u ** 2


def parts(rows: np.ndarray, n: int) -> list[np.ndarray]:
    """``rows`` (one stacked block) cut into at most ``n`` consecutive parts of two rows or more."""
    k = min(n, len(rows) // 2)
    return [rows] if k <= 1 else np.array_split(rows, k)


def _block(idx: np.ndarray, theta: np.ndarray):
    return inherited("gp_stack").block(idx, theta)


class SplitStack:
    """A ``gp_batch.Stack`` whose ``evaluate`` sends all but the first part of every block to ``pool``."""

    def __init__(self, stack, pool, n: int):
        self.stack, self.pool, self.n = stack, pool, n
        self.problems = stack.problems

    def evaluate(self, which: np.ndarray, theta: np.ndarray):
        lml, lp, grad = np.empty(len(which)), np.empty(len(which)), np.empty((len(which), 3))
        local, remote = [], []
        for rows in self.stack.blocks(which):
            first, *rest = parts(rows, self.n)
            local.append(first)
            remote.extend((r, self.pool.submit(_block, which[r], theta[r])) for r in rest)
        for r in local:
            lml[r], lp[r], grad[r] = self.stack.block(which[r], theta[r])
        for r, fut in remote:
            lml[r], lp[r], grad[r] = fut.result()
        return lml, lp, grad


@contextlib.contextmanager
def shared(stack, block: int, workers: int | None = None) -> Iterator:
    """``stack`` (a ``gp_batch.Stack``) for ``gp_batch.fit_stack``, its evaluations shared out over
    ``workers`` processes (this one and forked ones; default ``current_workers()``) within the
    block. Call it with one BLAS thread set (``threadpoolctl``), as the workers run with: a
    threaded product may sum in another order (other bits)."""

    runs = sum(len(p.starts) for p in stack.problems)
    n = min(current_workers() if workers is None else max(1, int(workers)), max(runs // 2, 1))
    if n > 1:
        import psutil

        limit = _WORKERS[1] or int(AUTO_SHARE * machine_memory())
        n = cap_workers("run.threads (the GP fit's worker processes)", n, worker_bytes(int(stack.u.max()), block),
                        limit, parent=float(psutil.Process().memory_info().rss))
    if n <= 1 or not can_fork():
        yield stack
        return
    # the workers inherit the stack and evaluate its rows
    with forked_pool(n - 1, {"gp_stack": stack}, initializer=_one_blas_thread) as pool:
        yield SplitStack(stack, pool, n)


def _one_blas_thread() -> None:
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
