"""The reference distribution of the design's t statistic (``design``): the wild cluster bootstrap-t.

Why: at the Holm levels (0.05/8) the multiway cluster-robust t of a rare binary metric has heavier
tails than t_df (docs/calibration.md measured familywise 7.1 % on 12 targets x 8 scans with track
noise dominant), so its p-value and adjusted interval read the tails of the statistic's own
bootstrap distribution instead.

The draw (unrestricted wild bootstrap, WCU; multiway as MacKinnon, Nielsen & Webb 2021): one weight
v per unit of the clustering level with the fewest units (``level``), y*_i = theta + v_{g(i)} e_i
with e = y - theta; the bootstrap statistic is the same t, t* = (theta* - theta) / sqrt(V*), V* the
same multiway variance (``design.variance``, with its rule for a non-positive sum) of y*. Weights:
Webb's six-point (+-sqrt(1/2), +-1, +-sqrt(3/2)) where that level has at most ``WEBB_BELOW`` units
(Rademacher's 2^G distinct draws are too few there), else Rademacher. The reference is |t*|: the
interval is theta +- q se with q its ``level`` quantile, p = (1 + #{|t*| >= |t|}) / (B + 1), so an
interval at 1 - a excludes 0 exactly when p <= a (both read the same order statistic).

Fast without a loop over draws: with S = M' diag(w e) C (units of a variance term x weight units)
and a = M' w, a term's sum of squared unit sums at draw v is v'(S'S)v - 2 d (S'a).v + d^2 a.a with
d = theta* - theta = (C' w e).v: a few matrix products over the B draws, for R replications at once.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import sparse

WEBB_BELOW = 12      # Webb's six-point weights at this many units or fewer (2^12 Rademacher draws)
WEBB = np.array([-math.sqrt(1.5), -1.0, -math.sqrt(0.5), math.sqrt(0.5), 1.0, math.sqrt(1.5)])


@lru_cache(maxsize=32)
def weights(G: int, B: int, seed: tuple) -> np.ndarray:
    """(B, G) wild weights, mean 0 and variance 1, shared by every statistic of one population
    (common random numbers), Webb's where ``G <= WEBB_BELOW``, else Rademacher."""
    rng = np.random.default_rng([*seed, 7])
    if G <= WEBB_BELOW:
        return WEBB[rng.integers(0, 6, size=(B, G))]
    return rng.integers(0, 2, size=(B, G)) * 2.0 - 1.0


def level(layout) -> str | None:
    """The clustering level whose units carry the weights: the one with the fewest units."""
    levels = layout.levels()
    return min(levels, key=lambda k: (levels[k], k)) if levels else None


def _codes(layout, names) -> np.ndarray:
    return np.unique(np.stack([layout.labels[k] for k in names], axis=1), axis=0, return_inverse=True)[1].ravel()


def abs_t(values: np.ndarray, layout, terms, n_boot: int, seed) -> np.ndarray:
    """(R, B) |t*| of R replications' leaf values (R, N): the reference of each one's t statistic.
    ``terms``: the design's inclusion-exclusion terms (sign, unit indicator (N, G), G) and whether
    each is a one-level term (``design._terms``)."""
    y = np.atleast_2d(np.asarray(values, float))
    R, N = y.shape
    w = np.asarray(layout.weights, float)
    wl = level(layout)
    cw = _codes(layout, [wl])
    Gw = int(cw.max()) + 1
    v = weights(Gw, int(n_boot), tuple(np.atleast_1d(seed).tolist()))                # (B, Gw)
    theta = y @ w
    we = (y - theta[:, None]) * w[None, :]                                           # (R, N)
    C = sparse.csr_matrix((np.ones(N), (np.arange(N), cw)), shape=(N, Gw))
    c = np.asarray(C.T @ we.T).T                                                     # (R, Gw)
    d = c @ v.T                                                                      # (R, B): theta* - theta
    iu = np.triu_indices(Gw)
    vv = v[:, iu[0]] * v[:, iu[1]] * np.where(iu[0] == iu[1], 1.0, 2.0)             # (B, Gw(Gw+1)/2)
    parts = []                                                                        # (Q, r, k) per term, c_g and sign in
    for sign, M, G, first in terms:
        a = np.asarray(M.T @ w).ravel()                                              # (G,)
        c_g = sign * G / (G - 1)
        pair = M.indices * Gw + cw
        if len(np.unique(pair)) == G:   # each unit within one weight unit: S'S is diagonal
            s = np.asarray(M.T @ we.T).T                                             # (R, G)
            home = np.zeros(G, dtype=np.int64)
            home[M.indices] = cw
            H = sparse.csr_matrix((np.ones(G), (np.arange(G), home)), shape=(G, Gw))
            Q = np.zeros((R, len(iu[0])))
            Q[:, iu[0] == iu[1]] = np.asarray(H.T @ (s * s).T).T
            r = np.asarray(H.T @ (s * a).T).T
        else:
            P = sparse.csr_matrix((np.ones(N), (np.arange(N), pair)), shape=(N, G * Gw))
            S = np.asarray(P.T @ we.T).T.reshape(R, G, Gw)                           # (R, G, Gw)
            Q, r = (S.transpose(0, 2, 1) @ S)[:, iu[0], iu[1]], S.transpose(0, 2, 1) @ a
        parts.append((c_g * Q, c_g * r, c_g * float(a @ a), first and sign > 0))

    def term(Q, r, k, rows=slice(None)):
        out = Q[rows] @ vv.T
        out -= 2 * d[rows] * (r[rows] @ v.T)
        out += d[rows] * d[rows] * k
        return out                                                                   # (R, B)

    V = term(*(sum(p[i] for p in parts) for i in range(3)))
    rows = np.flatnonzero((V <= 0).any(axis=1))
    if len(rows):   # CGM's rule, as ``design.variance``: the largest one-level variance stands in
        V[rows] = np.where(V[rows] > 0, V[rows], np.max([term(*p[:3], rows) for p in parts if p[3]], axis=0))
    se = np.sqrt(np.maximum(V, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(se > 0, np.abs(d) / se, np.where(np.abs(d) > 1e-12 * (np.abs(theta)[:, None] + 1), np.inf, 0.0))


def quantile(ref: np.ndarray, level: float) -> np.ndarray:
    """The ``level`` quantile of |t*| along the last axis: its k-th smallest, k = ceil(level (B + 1))
    (inf where k > B), the order statistic ``p_value`` compares with."""
    B = ref.shape[-1]
    k = math.ceil(level * (B + 1) - 1e-9)
    if k > B:
        return np.full(ref.shape[:-1], np.inf)
    return np.partition(ref, k - 1, axis=-1)[..., k - 1]


def p_value(ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(1 + #{|t*| >= |t|}) / (B + 1) along the last axis of ``ref``."""
    t = np.abs(np.asarray(t, float))
    return (1 + (ref >= t[..., None]).sum(axis=-1)) / (ref.shape[-1] + 1)
