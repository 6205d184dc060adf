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
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import sparse

from pipeline.infra import seeds

STREAM = 4096        # draws made from one random stream (fixed: the draws do not depend on how they are read)
CHUNK = 4096         # draws read at a time: memory stays bounded at any evaluate.bootstrap
QUADRATIC_UP_TO = 32 # weight units up to which the quadratic forms (B x G^2 / 2) beat the sparse unit sums
WEBB_BELOW = 12      # Webb's six-point weights at this many units or fewer (2^12 Rademacher draws)
WEBB = np.array([-math.sqrt(1.5), -1.0, -math.sqrt(0.5), math.sqrt(0.5), 1.0, math.sqrt(1.5)])


@lru_cache(maxsize=16)   # at most 16 x 4096 x G weights held
def _stream(G: int, seed: tuple, k: int) -> np.ndarray:
    """Draws k STREAM .. (k + 1) STREAM of the weights (cached: every statistic of a population reads them)."""
    rng = seeds.stream(seed[0], *seed[1:], "wild", k)
    block = (WEBB[rng.integers(0, 6, size=(STREAM, G))] if G <= WEBB_BELOW
             else rng.integers(0, 2, size=(STREAM, G)) * 2.0 - 1.0)
    block.setflags(write=False)
    return block


@lru_cache(maxsize=4)    # at most 4 x 4096 x 528 products (G <= QUADRATIC_UP_TO): 70 MB
def _stream_products(G: int, seed: tuple, k: int) -> np.ndarray:
    """(STREAM, G(G+1)/2) of ``_stream``'s draws: v_i v_j over the upper triangle, off-diagonal doubled."""
    v, (i, j) = _stream(G, seed, k), np.triu_indices(G)
    out = v[:, i] * v[:, j] * np.where(i == j, 1.0, 2.0)
    out.setflags(write=False)
    return out


def _read(stream, G: int, B: int, seed: tuple, start: int) -> list[np.ndarray]:
    """Rows ``start`` .. ``start + B`` of ``stream(G, seed, k)``'s blocks of ``STREAM``, block by block."""
    return [stream(G, seed, k)[max(start - k * STREAM, 0): min(start + B - k * STREAM, STREAM)]
            for k in range(start // STREAM, (start + B - 1) // STREAM + 1)]


def products(G: int, B: int, seed: tuple, start: int = 0) -> np.ndarray:
    """``weights``' quadratic products (B, G(G+1)/2), the same draws."""
    out = _read(_stream_products, G, B, seed, start)
    return np.concatenate(out) if len(out) > 1 else out[0]


def weights(G: int, B: int, seed: tuple, start: int = 0) -> np.ndarray:
    """(B, G) wild weights, mean 0 and variance 1, draws ``start`` .. ``start + B`` (made in blocks of
    ``STREAM`` from their own streams, so a chunked reader gets the same draws), shared by every
    statistic of one population (common random numbers); Webb's where ``G <= WEBB_BELOW``, else
    Rademacher."""
    out = _read(_stream, G, B, seed, start)
    return np.concatenate(out) if len(out) > 1 else (out[0] if out else np.zeros((0, G)))


def level(layout) -> str | None:
    """The clustering level whose units carry the weights: the one with the fewest units."""
    levels = layout.levels()
    return min(levels, key=lambda k: (levels[k], k)) if levels else None


def _codes(layout, names) -> np.ndarray:
    return np.unique(np.stack([layout.labels[k] for k in names], axis=1), axis=0, return_inverse=True)[1].ravel()


@dataclass(frozen=True)
class Plan:
    """What a layout's draws need, made once per layout (``design.Layout.wild_plan``): the weight
    units (``cw``, ``Gw``), the upper triangle of a Gw x Gw form, and per variance term its
    c_g (sign and G/(G - 1)), a = M'w, whether it is a one-level term, and how its S = M' diag(w e) C
    is gathered (``home``: each unit's weight unit where every unit lies in one, else ``P``)."""
    cw: np.ndarray
    Gw: int
    iu: tuple
    terms: list


def plan(layout) -> Plan:
    w = np.asarray(layout.weights, float)
    N = len(w)
    cw = _codes(layout, [level(layout)])
    Gw = int(cw.max()) + 1
    terms = []
    for sign, M, G, first in layout.terms:
        pair = M.indices * Gw + cw
        if len(np.unique(pair)) == G:   # each unit within one weight unit: S'S is diagonal
            home = np.zeros(G, dtype=np.int64)
            home[M.indices] = cw
            how = ("home", sparse.csr_matrix((np.ones(G), (np.arange(G), home)), shape=(G, Gw)))
        else:
            how = ("pairs", sparse.csr_matrix((np.ones(N), (np.arange(N), pair)), shape=(N, G * Gw)))
        terms.append((sign * G / (G - 1), M, G, np.asarray(M.T @ w).ravel(), first and sign > 0, how))
    return Plan(cw, Gw, np.triu_indices(Gw), terms)


def abs_t(values: np.ndarray, layout, n_boot: int, seed) -> np.ndarray:
    """(R, B) |t*| of R replications' leaf values (R, N): the reference of each one's t statistic
    (``layout``: a ``design.Layout``, its ``wild_plan``)."""
    y = np.atleast_2d(np.asarray(values, float))
    R, N = y.shape
    w = np.asarray(layout.weights, float)
    pl = layout.wild_plan
    cw, Gw, iu = pl.cw, pl.Gw, pl.iu
    seed = tuple(np.atleast_1d(seed).tolist())
    theta = y @ w
    we = (y - theta[:, None]) * w[None, :]                                           # (R, N)
    c = np.stack([np.bincount(cw, weights=row, minlength=Gw) for row in we])          # (R, Gw)
    if R == 1 and Gw > QUADRATIC_UP_TO:
        return _one(we[0], c[0], cw, Gw, pl.terms, int(n_boot), seed, abs(theta[0]))[None, :]
    parts = []                                                                        # (Q, r, k) per term, c_g and sign in
    for c_g, M, G, a, first, (kind, X) in pl.terms:
        if kind == "home":
            s = np.asarray(M.T @ we.T).T                                             # (R, G)
            Q = np.zeros((R, len(iu[0])))
            Q[:, iu[0] == iu[1]] = np.asarray(X.T @ (s * s).T).T
            r = np.asarray(X.T @ (s * a).T).T
        else:
            S = np.asarray(X.T @ we.T).T.reshape(R, G, Gw)                           # (R, G, Gw)
            Q, r = (S.transpose(0, 2, 1) @ S)[:, iu[0], iu[1]], S.transpose(0, 2, 1) @ a
        parts.append((c_g * Q, c_g * r, c_g * float(a @ a), first))
    total = tuple(sum(p[i] for p in parts) for i in range(3))
    out = np.empty((R, int(n_boot)))
    for k in range(0, int(n_boot), CHUNK):
        v = weights(Gw, min(CHUNK, int(n_boot) - k), seed, k)                        # (b, Gw)
        vv = products(Gw, len(v), seed, k)                                           # (b, Gw(Gw+1)/2)
        d = c @ v.T                                                                  # (R, b): theta* - theta

        def term(Q, r, k2, rows=slice(None)):
            t = Q[rows] @ vv.T
            t -= 2 * d[rows] * (r[rows] @ v.T)
            t += d[rows] * d[rows] * k2
            return t                                                                 # (R, b)

        V = term(*total)
        rows = np.flatnonzero((V <= 0).any(axis=1))
        if len(rows):   # CGM's rule, as ``design.variance``: the largest one-level variance stands in
            V[rows] = np.where(V[rows] > 0, V[rows], np.max([term(*p[:3], rows) for p in parts if p[3]], axis=0))
        out[:, k: k + len(v)] = _ratio(d, V, np.abs(theta)[:, None])
    return out


def _ratio(d: np.ndarray, V: np.ndarray, scale) -> np.ndarray:
    se = np.sqrt(np.maximum(V, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(se > 0, np.abs(d) / se, np.where(np.abs(d) > 1e-12 * (scale + 1), np.inf, 0.0))


def _one(we: np.ndarray, c: np.ndarray, cw: np.ndarray, Gw: int, terms, B: int, seed,
         scale: float) -> np.ndarray:
    """(B,) |t*| of one population (the engine's case): each term's unit sums U = S v - d a with S
    sparse (at most one entry per leaf), ``CHUNK`` draws at a time (memory bounded at any B);
    ``terms``: the plan's (c_g, M, G, a, one-level, ...)."""
    N = len(we)
    WE = sparse.csr_matrix((we, (np.arange(N), cw)), shape=(N, Gw))
    parts = [(c_g, (M.T @ WE).tocsr(), a, first) for c_g, M, G, a, first, _ in terms]   # S: (G, Gw)
    out = np.empty(B)
    for k in range(0, B, CHUNK):
        v = weights(Gw, min(CHUNK, B - k), seed, k)                                  # (b, Gw)
        d = v @ c
        ts = [(cg * ((S @ v.T - np.outer(a, d)) ** 2).sum(axis=0), first) for cg, S, a, first in parts]
        V = sum(t for t, _ in ts)
        V = np.where(V > 0, V, np.max([t for t, first in ts if first], axis=0))
        out[k: k + len(v)] = _ratio(d, V, scale)
    return out


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
