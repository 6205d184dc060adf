"""The batched GP fit's evaluations shared out over worker processes (pipeline/method/gp_workers.py):
every fit's hyperparameters, objective and run records the same bits for one, two and three
processes, the blocks cut only where a fit's numbers cannot move, and the worker count set by the
stage's context."""
from __future__ import annotations

import numpy as np
import pytest

import pipeline.method.gp_batch as gb
import pipeline.method.gp_workers as gw
from pipeline.infra.workers import can_fork
from tests.pipeline.method.test_gp_batch import _circle, _targets


def _problems(seed: int = 0, classes: int = 3, F: int = 8, restarts: int = 3, views: int = 12) -> list[gb.Problem]:
    """Fits on a few input sets of different sizes (so blocks of several sizes, and lone runs late
    in the lock step), with and without hyperpriors."""
    rng = np.random.default_rng(seed)
    out = []
    for c in range(classes):
        X = _circle(rng, views + 7 * c, repeat=1 + c % 2)
        Y = _targets(rng, X, F)
        lb = np.log(np.array([[1e-6, 1e2], [0.05, 10.0], [1e-6, 1.0]]))
        prior = np.array([[2.0, 0.5], [2.5, 1e-3]]) if c % 2 == 0 else np.full((2, 2), np.nan)
        for f in range(F):
            y = Y[f] - Y[f].mean()
            out.append(gb.Problem(X, y, lb, prior, gb.starts_for(np.zeros(3), lb, restarts, 100 * c + f)))
    return out


def _bits(results: list[gb.Result]) -> list[tuple]:
    return [(r.theta.tobytes(), np.float64(r.objective).tobytes(), np.float64(r.lml).tobytes(), r.start,
             [(x["status"], x["nit"], x["nfev"], x["message"]) for x in r.runs]) for r in results]


def test_a_lone_matrix_is_summed_in_another_order():
    """Why blocks are never cut into parts of one row: the stacked objective of one fit alone may
    differ in its last bits from the same fit's row in a larger stack (numpy's einsum, seen on
    120-view rings as the synthetic run's), while any stack of two or more rows gives the row's
    bits of the full stack."""
    stack = gb.Stack(_problems(1, classes=1, F=12, views=120))
    rng = np.random.default_rng(2)
    theta = np.c_[rng.uniform(-3, 1, 12), rng.uniform(-2, 1.5, 12), rng.uniform(-9, -1, 12)]
    which = np.arange(12)
    full = stack.block(which, theta)
    for part in gw.parts(which, 5) + gw.parts(which, 2) + [which[:2], which[-3:]]:
        assert len(part) >= 2
        got = stack.block(which[part], theta[part])
        for a, b in zip(full, got):
            assert a[part].tobytes() == b.tobytes()


def test_parts_are_of_two_rows_or_more():
    rows = np.arange(7)
    assert [len(p) for p in gw.parts(rows, 2)] == [4, 3]
    assert [len(p) for p in gw.parts(rows, 5)] == [3, 2, 2]
    assert [len(p) for p in gw.parts(np.arange(3), 2)] == [3]
    assert [len(p) for p in gw.parts(np.arange(1), 4)] == [1]
    assert np.concatenate(gw.parts(rows, 3)).tolist() == rows.tolist()


def _fit(problems, workers: int, memory_budget: int = 8 << 30) -> list[tuple]:
    with gw.fit_workers(workers, memory_budget):
        return _bits(gb.fit_problems(problems))


@pytest.mark.skipif(not can_fork(), reason="the shared fit forks its workers; this platform cannot fork")
def test_the_fits_are_the_same_bits_for_any_worker_count():
    problems = _problems()
    one = _fit(problems, 1)
    assert _fit(problems, 2) == one
    assert _fit(problems, 3) == one
    assert gw.current_workers() == 1   # outside the stage's switch: one process


def test_the_memory_budget_caps_the_workers(caplog):
    """A budget that holds no second worker beside this process: the fit runs here, logged."""
    problems = _problems(3, classes=1, F=2, restarts=1)
    ref = _fit(problems, 1)
    with caplog.at_level("WARNING"):
        assert _fit(problems, 4, memory_budget=1) == ref
    assert "capped to 1 worker" in caplog.text
