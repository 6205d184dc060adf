"""The one check of a fusion method's output, built-in or registered from outside, wherever a
method is called (``viewfuse.fuse``, the population grid's fusion and single-view calls).

A method returns log posteriors over its C candidates after each of K steps. What comes back is
checked once, here: its shape, its values (NaN and +inf refused; -inf allowed, it is a probability
that underflowed) and that each posterior is normalised in probability space (logsumexp over
the classes within ``TOLERANCE`` of 0); only real floating-point arrays are log posteriors (a
complex, string, object, integer or boolean array is refused, not coerced). A method that raises
(``SystemExit`` and any other ``BaseException`` but ``KeyboardInterrupt``, which stops the run as
the user asked) or that runs past its time limit is named too; it reads its input through
read-only views (``pipeline.method.call_guard``). Every failure is a ``MethodOutputError`` (an
``ExtensionError``) naming the method key, the hook and what was wrong, so a researcher's method
fails where it is called, not as a KeyError or a P(truth) of 20 three stages later.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from pipeline.infra.extension import ExtensionError
from pipeline.method.call_guard import MethodTimeout, read_only, time_limit
from pipeline.method import call_guard

# |logsumexp over classes| allowed: float64 rounding of a normalised posterior is ~1e-15; a method
# that normalises in float32 is within ~1e-6. Larger is a posterior that does not sum to one.
TOLERANCE = 1e-6


class MethodOutputError(ExtensionError):
    """A fusion method raised, or returned what no posterior can be (names the method key)."""


def _floats(where: str, out, what: str) -> np.ndarray:
    """``out`` as a real floating-point array, or ``MethodOutputError``: other dtypes are refused,
    not coerced (a complex posterior would lose its imaginary part, text would be parsed)."""
    try:
        raw = np.asarray(out)
    except (TypeError, ValueError) as e:
        raise MethodOutputError(f"{where} returned {type(out).__name__}, not an array of {what} ({e})") from None
    if raw.dtype.kind != "f":
        raise MethodOutputError(f"{where} returned an array of dtype {raw.dtype} ({type(out).__name__}), not "
                                f"real floating-point {what}")
    a = raw.astype(float, copy=False)
    return a if a.flags.writeable else a.copy()


def n_classes(t) -> int | None:
    """How many candidates a track input has: the GP bank's classes, else a provider's models'
    (their ``classes``), else the last axis of ``own`` (None when nothing says)."""
    for models in (t.gp, *t.models.values()):
        classes = getattr(models, "classes", None)
        if classes is not None:
            return len(classes)
    return None if t.own is None else int(np.shape(t.own)[-1])


def expected_shape(m, t, *, hook: str = "fuse") -> tuple[int | None, ...]:
    """The shape ``hook`` must return for track input ``t`` (None: any length on that axis):
    (R, K, C) from a pose-using method's ``fuse``, (K, C) from a pose-free one's and from
    ``single_view``."""
    K = int(np.shape(t.dropout)[0])
    C = n_classes(t)
    if hook == "fuse" and m.uses_poses:
        R = None if t.estimates is None else int(np.shape(t.estimates)[0])
        return (R, K, C)
    return (K, C)


def problem(a: np.ndarray, shape: tuple[int | None, ...], *, tol: float = TOLERANCE) -> str | None:
    """What is wrong with float array ``a`` as log posteriors of ``shape`` over the last axis
    (None: nothing). The one rule, also for posteriors handed to ``viewfuse.track_metrics``."""
    want = "(" + ", ".join("?" if n is None else str(n) for n in shape) + ")"
    if a.ndim != len(shape) or any(n is not None and n != s for n, s in zip(shape, a.shape)):
        return f"has shape {a.shape}; expected {want} (steps K from the track, classes C from the candidates)"
    if a.size == 0:
        return f"is empty (shape {a.shape})"
    bad = np.isnan(a)
    if bad.any():
        return f"holds NaN in {int(bad.sum())} of {a.size} entries"
    bad = np.isposinf(a)
    if bad.any():
        return f"holds +inf in {int(bad.sum())} of {a.size} entries (log posteriors are <= 0)"
    top = a.max(axis=-1, keepdims=True)
    if np.isneginf(top).any():
        return "holds a posterior that is -inf for every class (probability 0 everywhere)"
    lse = (top + np.log(np.exp(a - top).sum(axis=-1, keepdims=True)))[..., 0]
    off = np.abs(lse)
    if (off > tol).any():
        i = np.unravel_index(int(off.argmax()), off.shape)
        return (f"is not normalised: the probabilities of posterior {tuple(int(j) for j in i)} sum to "
                f"{np.exp(lse[i]):.6g}, not 1 (log-sum-exp {lse[i]:.3g}, tolerance {tol:g}; log posteriors expected)")
    return None


def check_output(key: str, out, shape: tuple[int | None, ...], *, hook: str = "fuse",
                 tol: float = TOLERANCE) -> np.ndarray:
    """``out`` as a float array when it is log posteriors of ``shape``; else ``MethodOutputError``
    naming ``key``, the hook and the problem."""
    where = f"fusion method {key!r} ({hook})"
    a = _floats(where, out, "log posteriors")
    bad = problem(a, shape, tol=tol)
    if bad is not None:
        raise MethodOutputError(f"{where}: its output {bad}")
    return a


def call_checked(m, hook: str, t, *, shape: tuple[int | None, ...] | None = None,
                 call: Callable | None = None, seconds: float | None = None,
                 setting: str = "run.method_seconds"):
    """``m.<hook>(t)`` (or ``call(t)``) on read-only views of ``t``'s arrays, stopped after
    ``seconds`` (default ``call_guard.TIME_LIMIT``; ``setting`` names where the limit is set), its
    error or its output named by the method's key. The output (the first element for
    ``fuse_with_extras``) is checked against ``shape`` (default ``expected_shape``;
    ``simulate``'s, probabilities, by ``check_probabilities``); a ``single_view`` that returns None
    (no single-view reading) passes."""
    fn = call or getattr(m, hook)
    limit = call_guard.TIME_LIMIT if seconds is None else seconds
    try:
        with time_limit(limit, "fusion method", m.key, hook, setting):
            out = fn(read_only(t))
    except (MemoryError, KeyboardInterrupt, MethodTimeout):
        raise   # the budget's, the user's and the limit's: kept as they are (the last names the method)
    except BaseException as e:  # noqa: BLE001 - SystemExit too: re-raised with the method's key
        raise MethodOutputError(f"fusion method {m.key!r} ({hook}) failed: {type(e).__name__}: {e}",
                                kind="fusion method", key=m.key, hook=hook, cause=f"{type(e).__name__}: {e}") from e
    if hook == "single_view" and out is None:
        return None
    if hook == "simulate":   # the simulation's posteriors are probabilities
        return check_probabilities(m.key, out, shape)
    want = expected_shape(m, t, hook="single_view" if hook == "single_view" else "fuse") if shape is None else shape
    if hook == "fuse_with_extras":
        if not (isinstance(out, tuple) and len(out) == 2 and isinstance(out[1], dict)):
            raise MethodOutputError(f"fusion method {m.key!r} (fuse_with_extras) must return "
                                    f"(log posteriors, dict), got {type(out).__name__}")
        return check_output(m.key, out[0], want, hook=hook), out[1]
    return check_output(m.key, out, want, hook=hook)


def check_probabilities(key: str, out, shape: tuple[int | None, ...], *, hook: str = "simulate",
                        tol: float = TOLERANCE):
    """``out`` as it is when it is posteriors in probability space (the simulation's ``simulate``)
    of ``shape``: no negative entry, and their logs pass ``problem``; else ``MethodOutputError``."""
    where = f"fusion method {key!r} ({hook})"
    a = _floats(where, out, "posteriors")
    if (a < 0).any():
        raise MethodOutputError(f"{where}: its output holds negative probabilities")
    with np.errstate(divide="ignore"):
        bad = problem(np.log(a), shape, tol=tol)
    if bad is not None:
        raise MethodOutputError(f"{where}: its output (as log probabilities) {bad}")
    return out
