"""The leave-one-target-out check's previous route, kept as the reference the jackknife-after-bootstrap
one (``pipeline.evaluation.statistics.hierarchy.leave_one_out``) is compared with: each subset of
targets re-resampled with its own draws (T resamplers of T - 1 targets: quadratic in targets)."""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.statistics import records as REC
from pipeline.evaluation.statistics.resampler import draws


def without(h, ti: int):
    """The resampler of every target of ``h`` but ``ti`` (its own draws) and the kept indices."""
    keep = np.array([k for k in range(len(h.units[0])) if k != ti])
    sizes = [len(h.units[0][k][1]) for k in keep]
    return draws([sizes], h.n_boot, [*np.atleast_1d(h.seed), 2, ti]), keep


def estimates(h, values: np.ndarray, pool: str) -> list[dict]:
    """Each target's left-out estimate of the engine's statistic, re-resampled."""
    out = []
    for ti in range(len(h.targets)):
        rs, keep = without(h, ti)
        out.append(rs.estimate(values[:, keep][:, :, : rs.shape[2]], pool))
    return out


def leave_one_out(h, values: np.ndarray, pool: str, higher: bool) -> dict:
    """The previous route's {"loto_min", "loto_max", "loto_flips"}."""
    full = REC.outcome(*(lambda e: (e["ci_low"], e["ci_high"]))(h.target_rs.estimate(values, pool)), higher)
    ests = estimates(h, values, pool)
    v = np.array([e["value"] for e in ests], float)
    v = v[np.isfinite(v)]
    flips = [t for t, e in zip(h.targets, ests) if REC.outcome(e["ci_low"], e["ci_high"], higher) != full]
    return {"loto_min": float(v.min()), "loto_max": float(v.max()), "loto_flips": flips}
