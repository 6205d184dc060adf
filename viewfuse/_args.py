"""The checks at the door of the public API: every argument's type, shape, range and size is
checked before any work, and a bad one is a ``TypeError`` (wrong kind) or ``ValueError`` (wrong
value) whose message starts with the function and names the argument, never an ``IndexError`` or
a numpy error from deep inside. ``affordable`` refuses a call whose estimated memory or time is
beyond the machine before anything is allocated (the estimates are rules of thumb, right within a
small factor, written beside each caller in ``viewfuse.api``)."""
from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from pipeline.infra.budget import machine_memory
from pipeline.infra.budget import gib

# A call may take this share of the memory available now (the rest is the interpreter's, the
# caller's arrays', the engine's temporaries beyond the estimate).
MEMORY_SHARE = 0.5


def _fail(fn: str, name: str, text: str, exc: type[Exception] = ValueError):
    raise exc(f"{fn}: {name} {text}")


def integer(fn: str, name: str, v, *, lo: int | None = None, hi: int | None = None) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        _fail(fn, name, f"must be an integer, got {type(v).__name__} {v!r:.60}", TypeError)
    v = int(v)
    if lo is not None and v < lo:
        _fail(fn, name, f"must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        _fail(fn, name, f"must be <= {hi}, got {v}")
    return v


def real(fn: str, name: str, v, *, lo: float | None = None, hi: float | None = None, open_lo: bool = False) -> float:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        _fail(fn, name, f"must be a real number, got {type(v).__name__} {v!r:.60}", TypeError)
    v = float(v)
    if not np.isfinite(v):
        _fail(fn, name, f"must be finite, got {v}")
    if lo is not None and (v < lo or (open_lo and v == lo)):
        _fail(fn, name, f"must be {'>' if open_lo else '>='} {lo}, got {v}")
    if hi is not None and v > hi:
        _fail(fn, name, f"must be <= {hi}, got {v}")
    return v


def string(fn: str, name: str, v) -> str:
    if not isinstance(v, str):
        _fail(fn, name, f"must be a string, got {type(v).__name__} {v!r:.60}", TypeError)
    return v


def array(fn: str, name: str, v, *, ndim: int | tuple[int, ...], shape: tuple[int | None, ...] | None = None,
          dims: str = "", finite: bool = True) -> np.ndarray:
    """``v`` as a float array of ``ndim`` axes (one of, when a tuple), each of length >= 1, equal
    to ``shape``'s where given (None: any), and finite unless told."""
    if isinstance(v, (str, bytes, dict)) or v is None:
        _fail(fn, name, f"must be an array of numbers {dims}, got {type(v).__name__}", TypeError)
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as e:
        _fail(fn, name, f"must be an array of numbers {dims}, not {type(v).__name__} ({e})", TypeError)
    allowed = (ndim,) if isinstance(ndim, int) else ndim
    if a.ndim not in allowed:
        _fail(fn, name, f"must be {dims or f'{allowed[0]}-D'}, got shape {a.shape}")
    if 0 in a.shape:
        _fail(fn, name, f"must not be empty, got shape {a.shape}")
    if shape is not None:   # one length per axis, None for any, aligned at the last axis
        for axis in range(1, min(len(shape), a.ndim) + 1):
            if shape[-axis] is not None and shape[-axis] != a.shape[-axis]:
                _fail(fn, name, f"must be {dims}: axis {a.ndim - axis} must have length {shape[-axis]}, "
                                f"got shape {a.shape}")
    if finite and not np.isfinite(a).all():
        _fail(fn, name, f"must be finite, got {int((~np.isfinite(a)).sum())} NaN or infinite entries")
    return a


def instance(fn: str, name: str, v, cls: type | tuple[type, ...], what: str) -> Any:
    if not isinstance(v, cls):
        _fail(fn, name, f"must be {what}, got {type(v).__name__}", TypeError)
    return v


def available_memory() -> int:
    """Bytes a call may allocate now: the memory available (physical or the cgroup's limit,
    ``pipeline.infra.budget.machine_memory``) times ``MEMORY_SHARE``."""
    import psutil

    return int(MEMORY_SHARE * min(int(psutil.virtual_memory().available), machine_memory()))


def affordable(fn: str, names: str, nbytes: float, seconds: float | None = None,
               max_seconds: float | None = None) -> None:
    """Refuse (``ValueError`` naming the arguments ``names``) a call estimated to need more than
    ``available_memory()`` bytes or more than ``max_seconds`` seconds."""

    limit = available_memory()
    if nbytes > limit:
        _fail(fn, names, f"would need about {gib(nbytes)} of memory (estimate, before anything is allocated); "
                         f"{gib(limit)} may be used now ({MEMORY_SHARE:.0%} of the available memory): make them smaller")
    if seconds is not None and max_seconds is not None and seconds > max_seconds:
        _fail(fn, names, f"would take about {seconds:.0f} s (estimate, single core), over max_seconds = "
                         f"{max_seconds:g}: make them smaller or raise max_seconds")
