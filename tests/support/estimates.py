"""The one check of a stage's estimate against the seconds a finished run recorded (pipeline/infra/cost.py).

The idle wall time an estimate stands for lies between the stage's CPU seconds over the cores (every
core busy all along) and the wall seconds recorded (equal idle, longer under load) on the machine the
estimates stand for: estimate <= 2 x wall, and estimate >= CPU / cores / 2. On another machine the check reads that machine's speed too,
which is why a live run is checked in ``make bench`` (tests/bench/bench_chains.py) and ``make test``
checks only recorded runs (tests/pipeline/infra/test_cost_recorded.py).
"""
from __future__ import annotations


def misfit(stage: str, est: float, seconds: float, cpu_seconds: float, cores: int) -> str | None:
    """Why ``est`` is not within a factor of two of the record, or None."""
    if est > 2 * seconds:
        return f"{stage}: estimated {est:.1f} s, over twice the {seconds:.1f} s wall it took"
    if est < cpu_seconds / cores / 2:
        return f"{stage}: estimated {est:.1f} s, under half its {cpu_seconds:.1f} CPU s over {cores} cores"
    return None
