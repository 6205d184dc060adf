"""Tolerances for comparing two float32 evaluations of one computation that differ only in the
order of their operations (memory layout, chunking, oneDNN against BLAS kernels).

Which order a kernel takes depends on the processor (vector width, oneDNN's dispatch), so a fixed
bound such as 1e-6 sits at one machine's rounding noise and tips on another (1.25e-6 on an AMD
EPYC). The worst-case bound (n·u·|W||x| per layer) is vacuous for a deep network (~1e9 for
AlexNet's weights), so the bound is read off the arithmetic instead: the same route evaluated in
float64 gives the float32 route's own rounding error e on these inputs; another order's error has
the same law, so two float32 routes differ by at most e₁ + e₂ ≈ 2e, doubled for the spread of a
maximum over a tensor between orders. A real difference between the routes (a wrong mask, a
dropped bias, another layer) moves scores by ~1e-2, far above it.
"""
from __future__ import annotations

import numpy as np

U32 = 2.0 ** -24    # float32 unit roundoff


def _arr(x) -> np.ndarray:
    return np.asarray(x.detach().cpu().double() if hasattr(x, "detach") else x, np.float64)


def rounding_tol(ref32, ref64) -> float:
    """4 × max |ref32 − ref64| (the measured float32 rounding error of one route), at least 4 u
    × the largest value (an exactly rounded result still leaves the other route its last bit)."""
    a, b = _arr(ref32), _arr(ref64)
    return 4.0 * max(float(np.abs(a - b).max()), U32 * float(np.abs(b).max()))
