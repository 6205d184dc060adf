"""Keeping freed large blocks in the process heap while a torch loop runs (glibc only).

glibc serves every allocation above its mmap threshold (at most 32 MB, 128 kB by default) with a
fresh ``mmap`` and unmaps it on free. A training step of the classifier frees and reallocates
hundreds of MB of such blocks (the bf16 copies of the head's weight matrices, their gradients,
activations), so each step faults every page in again: about 10^5 minor page faults per step,
roughly a third of the step's CPU time on this machine (``make bench`` prints the split). Raising
both thresholds while the loop runs lets freed blocks be reused; on exit the defaults come back and
the heap is trimmed, so later stages see the usual behaviour. Numerics are not affected.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import contextlib

# mallopt parameters (glibc malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
DEFAULT_THRESHOLD = 128 * 1024          # glibc's documented default for both
KEEP_THRESHOLD = 1 << 30                # 1 GiB: every tensor of a training step stays in the heap


def _libc():
    """glibc's ``mallopt``/``malloc_trim``, or None (musl, macOS, Windows: nothing to tune)."""
    name = ctypes.util.find_library("c")
    if not name:
        return None
    try:
        libc = ctypes.CDLL(name)
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    except OSError:  # pragma: no cover
        return None


@contextlib.contextmanager
def reuse_freed_memory():
    """Inside the block, freed large allocations stay in the heap for reuse (see module doc).
    Yields whether the setting took effect (False where the C library is not glibc)."""
    libc = _libc()
    ok = bool(libc) and libc.mallopt(M_MMAP_THRESHOLD, KEEP_THRESHOLD) == 1 \
        and libc.mallopt(M_TRIM_THRESHOLD, KEEP_THRESHOLD) == 1
    try:
        yield ok
    finally:
        if libc:
            libc.mallopt(M_MMAP_THRESHOLD, DEFAULT_THRESHOLD)
            libc.mallopt(M_TRIM_THRESHOLD, DEFAULT_THRESHOLD)
            libc.malloc_trim(0)
