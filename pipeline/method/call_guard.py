"""What every call of a fusion method runs inside (``output_check.call_checked``), so that one
method cannot change another's numbers or hang a run:

- ``read_only``: the method reads its ``TrackInput`` (or the simulation's draws) through read-only
  views of the arrays, so a method that writes into ``t.own`` or ``t.dropout`` fails, named,
  instead of changing what the methods after it read (and ``vf.fuse`` never changes the caller's
  arrays). Views cost nothing; the arrays themselves are not copied.
- ``time_limit``: a call that has not returned after ``seconds`` is stopped by a SIGALRM timer
  (``setitimer``: one system call to arm and one to disarm, so it costs nothing per call) whose
  handler raises ``MethodTimeout`` naming the method and hook. It acts in a process's main thread,
  where ``vf.fuse`` and the evaluate stage's cells run (in this process or in its forked workers);
  elsewhere (another thread, a platform without SIGALRM) the call runs unbounded. A method blocked
  inside compiled code that never returns to Python is stopped when it does. An outer timer that
  would fire sooner is left to fire; one that would fire later is re-armed afterwards.

``TIME_LIMIT`` is the limit ``call_checked`` uses when its caller gives none: 0 (none) until the
evaluate stage sets ``run.method_seconds`` (its forked workers inherit it).
"""
from __future__ import annotations

import dataclasses
import signal
import threading
import time
from contextlib import contextmanager

import numpy as np

from pipeline.infra.extension import ExtensionError

TIME_LIMIT = 0.0


class MethodTimeout(ExtensionError):
    """A fusion method's call ran past its time limit and was stopped."""


def set_time_limit(seconds: float) -> float:
    """Make ``seconds`` (0: none) the default limit of every method call; returns the old one."""
    global TIME_LIMIT
    old, TIME_LIMIT = TIME_LIMIT, float(seconds or 0.0)
    return old


def _ro(a):
    if isinstance(a, np.ndarray) and a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


def read_only(t):
    """``t`` (a dataclass instance) with each array field replaced by a read-only view; anything
    else as it is."""
    if not dataclasses.is_dataclass(t) or isinstance(t, type):
        return t
    arrays = {f.name: _ro(getattr(t, f.name)) for f in dataclasses.fields(t)
              if f.init and isinstance(getattr(t, f.name, None), np.ndarray)}
    return dataclasses.replace(t, **arrays) if arrays else t


@contextmanager
def time_limit(seconds: float | None, kind: str, key: str, hook: str, setting: str = "run.method_seconds"):
    """Raise ``MethodTimeout`` in the body when it runs past ``seconds`` (None or 0: no limit)."""
    usable = (seconds and seconds > 0 and hasattr(signal, "setitimer")
              and threading.current_thread() is threading.main_thread())
    if not usable:
        yield
        return
    outer_delay, outer_interval = signal.getitimer(signal.ITIMER_REAL)
    if 0 < outer_delay <= seconds:       # an outer timer fires first: it stays in charge
        yield
        return

    def stop(signum, frame):
        raise MethodTimeout.of(kind, key, hook, f"did not return within {seconds:g} s and was stopped "
                                                f"(the time limit: {setting})")

    old = signal.signal(signal.SIGALRM, stop)
    t0 = time.monotonic()
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if outer_delay > 0:
            left = max(outer_delay - (time.monotonic() - t0), 1e-3)
            signal.setitimer(signal.ITIMER_REAL, left, outer_interval)
