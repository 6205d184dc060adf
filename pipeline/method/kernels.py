"""Compiled per-trajectory kernels of the fusion engine (numba, ``nogil``: worker threads run them
in parallel).

After the joint predictive of one (class, component) GP is formed for a block of B trajectories
(``pipeline/method/engine.py``), everything else a trajectory needs is O(K³) work on K×K
matrices: far too small for BLAS, and in numpy a long chain of temporaries (the engine before this
one spent half its time there). Here one loop per trajectory does it in registers and the L1
cache: the Cholesky factor of the covariance, the rows of M = L⁻¹, the conditional mean and
variance of each step given the past (pipeline/method/fusion.py's module docstring), the Gaussian
log density of every dropout sample, and finally the recursion over the track with the mean over
localization samples, in log space.

Arithmetic is plain IEEE double except in ``_gram`` and ``_sparse_z``, whose sums may be reassociated
(summed in SIMD lanes): a different rounding order, no other change. Results equal the
reference engine to rounding (tests/test_engine.py).
"""
from __future__ import annotations

import math
import os

import numpy as np
from numba import njit

# Compiling these takes each new process 10-30 s. numba keeps the machine code between processes
# only where NUMBA_CACHE_DIR names a folder: by default nothing is written outside the run
# folder, and a user (or the test suite, which starts dozens of processes) opts in by setting it.
_CACHE = bool(os.environ.get("NUMBA_CACHE_DIR"))
_NJIT = dict(nogil=True, cache=_CACHE, fastmath=False, error_model="numpy", boundscheck=False)
_NJIT_SUMS = {**_NJIT, "fastmath": {"reassoc", "contract"}}   # sums may be reassociated (module docstring)


@njit(**_NJIT_SUMS)
def _gram(Z, w, A):
    """A[i, j] = Σ_{p < P} w_p Z[i, p] Z[j, p] for j <= i (the lower triangle of Z diag(w) Zᵀ),
    Z (K, ≥ P), P = len(w)."""
    K = Z.shape[0]
    P = w.shape[0]
    for i in range(K):
        for j in range(i + 1):
            t = 0.0
            for p in range(P):
                t += w[p] * Z[i, p] * Z[j, p]
            A[i, j] = t


@njit(**_NJIT_SUMS)
def _sparse_z(F, idx, val, z):
    """z[i, p] = Σ_t val[p, t] F[i, idx[p, t]]: z = Q φ for Q's sparse form, F (K, ≥ P) features."""
    K = F.shape[0]
    P, r = idx.shape
    for i in range(K):
        for p in range(P):
            t = 0.0
            for j in range(r):
                t += val[p, j] * F[i, idx[p, j]]
            z[i, p] = t


@njit(**_NJIT)
def _fill(cov, Z, w, idx, val, b, ones, zbuf, A):
    """The lower triangle of trajectory b's covariance without the diagonal term, into A (K, K):
    per ``engine.per_gp``, from Q's sparse form (idx not empty), a weighted Gram (w not empty),
    or cov[b]."""
    K = A.shape[0]
    if idx.shape[0] > 0:
        _sparse_z(Z[b], idx, val, zbuf)
        _gram(zbuf, ones, A)
    elif w.shape[0] > 0:
        _gram(Z[b], w, A)
    else:
        for i in range(K):
            for j in range(i + 1):
                A[i, j] = cov[b, i, j]


# Trajectories factored side by side: every K×K step below is a loop over the T lanes, which the
# compiler turns into SIMD instructions (one 9×9 Cholesky alone is too small and too serial).
T = 8


@njit(**_NJIT)
def _tile_scratch(K, P):
    """The arrays ``_tile_factor`` works in: (A, L, M, Ld, g, zbuf, ones) for K steps and P features."""
    return (np.zeros((K, K, T)), np.zeros((K, K, T)), np.zeros((K, K, T)), np.empty((K, T)),
            np.empty((K, K)), np.empty((K, P)), np.ones(P))


@njit(**_NJIT)
def _tile_factor(cov, Z, w, idx, val, b0, nt, diag_add, ws):
    """Cholesky rows of trajectories b0 .. b0+nt-1 side by side (lane t = trajectory b0 + t), in
    the arrays ws of ``_tile_scratch``: A[:, :, t] the covariance (``_fill``) plus diag_add, L its
    factor, M = L⁻¹, Ld = diag(L), all (K, K, T) or (K, T), lower triangles only; g, zbuf, ones
    scratch for ``_fill``. Returns the first lane that is not positive definite, or -1."""
    A, L, M, Ld, g, zbuf, ones = ws
    K = A.shape[0]
    for t in range(nt):
        _fill(cov, Z, w, idx, val, b0 + t, ones, zbuf, g)
        for i in range(K):
            for j in range(i + 1):
                A[i, j, t] = g[i, j]
    for j in range(K):
        for t in range(nt):
            A[j, j, t] += diag_add
        for i in range(j):
            for t in range(nt):
                A[j, j, t] -= L[j, i, t] * L[j, i, t]
        for t in range(nt):
            if not A[j, j, t] > 0.0:
                return t
        for t in range(nt):
            Ld[j, t] = math.sqrt(A[j, j, t])
            M[j, j, t] = 1.0 / Ld[j, t]
        for i in range(j + 1, K):
            for m in range(j):
                for t in range(nt):
                    A[i, j, t] -= L[i, m, t] * L[j, m, t]
            for t in range(nt):
                L[i, j, t] = A[i, j, t] * M[j, j, t]
    for k in range(1, K):
        for m in range(k):              # M[k, :k] = -(L[k, :k] @ M[:k, :k]) / L_kk
            for t in range(nt):
                M[k, m, t] = 0.0
            for j in range(m, k):
                for t in range(nt):
                    M[k, m, t] += L[k, j, t] * M[j, m, t]
            for t in range(nt):
                M[k, m, t] *= -M[k, k, t]
    return -1


@njit(**_NJIT)
def _t_const(nu):
    """``student_t.log_const``: log t_ν's constant relative to the Gaussian's left-out -log(2π)/2."""
    return (math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu) - 0.5 * math.log(nu * math.pi)
            + 0.5 * math.log(2.0 * math.pi))


@njit(**_NJIT)
def wu_loglik(cov, Z, w, idx, val, diag_add, mu, mz, vz, smp, n_per, ll, vprod, nu=0.0):
    """Add one GP's term to ll (B, K, S) and vprod (B, K): for trajectory b (realization b // n_per),
    step k and dropout sample s, log N(s; μ_z,k - L_kk y_k, v) = -(s - mean)²/(2v) - log(v)/2 (up
    to -log(2π)/2): the first part goes to ll, v multiplies vprod (one log for all components later,
    in ``recursion_mean``; ``_times_var`` keeps the product in range).

    The joint predictive covariance (cov, Z, w, idx, val) is described in ``engine.per_gp``, plus
    diag_add·I; mu (B, K) predictive means, mz / vz (r, K) past dropout means / floored
    variances, smp (r, K, S) the samples.
    ``nu`` > 0: a Student-t of ν = nu degrees of freedom with the same location and squared scale
    (``pipeline.method.student_t``): -(ν+1)/2 log(1 + (s - mean)²/(ν v)) plus its constant in ll;
    0 (default): the Gaussian.
    Returns the index of a trajectory whose covariance is not positive definite, or -1.
    """
    B, K = mu.shape
    S = smp.shape[2]
    heavy = nu > 0.0
    a_t = -0.5 * (nu + 1.0)
    c_t = _t_const(nu) if heavy else 0.0
    ws = _tile_scratch(K, idx.shape[0])
    M, Ld = ws[2], ws[3]
    d = np.empty((K, T))
    v = np.empty((K, T))
    y = np.empty(T)
    q = np.empty(T)
    for b0 in range(0, B, T):
        nt = min(T, B - b0)
        bad = _tile_factor(cov, Z, w, idx, val, b0, nt, diag_add, ws)
        if bad >= 0:
            return b0 + bad
        for t in range(nt):
            r = (b0 + t) // n_per
            for j in range(K):
                d[j, t] = mz[r, j] - mu[b0 + t, j]
                v[j, t] = vz[r, j]
        for k in range(K):
            for t in range(nt):
                y[t] = M[k, k, t] * d[k, t]
                q[t] = 0.0
            for j in range(k):
                for t in range(nt):
                    y[t] += M[k, j, t] * d[j, t]
                    q[t] += M[k, j, t] * M[k, j, t] * v[j, t]
            for t in range(nt):
                b = b0 + t
                r = b // n_per
                lkk = Ld[k, t]
                var = lkk * lkk * (1.0 + q[t])
                h = -0.5 / var
                cm = mz[r, k] - lkk * y[t]
                if heavy:
                    inv = 1.0 / (nu * var)
                    for s in range(S):
                        e = smp[r, k, s] - cm
                        ll[b, k, s] += a_t * math.log1p(e * e * inv) + c_t
                else:
                    for s in range(S):
                        e = smp[r, k, s] - cm
                        ll[b, k, s] += h * e * e
                _times_var(vprod, ll, b, k, var)
    return -1


@njit(**_NJIT)
def _times_var(vprod, ll, b, k, v):
    """vprod[b, k] *= v; where the product would leave the normal range, the old product goes into
    ll[b, k, :] as -log(vprod)/2 first and the product restarts at v."""
    p = vprod[b, k] * v
    if not (1e-250 < p < 1e250):
        lg = -0.5 * math.log(vprod[b, k])
        for s in range(ll.shape[2]):
            ll[b, k, s] += lg
        p = v
    vprod[b, k] = p


@njit(**_NJIT)
def mb_loglik(cov, Z, w, idx, val, diag_add, mu, z, ll, vprod, nu=0.0):
    """Add one GP's term to ll (B, K, 1) and vprod (B, K): the chain rule of one Gaussian,
    -y_k²/2 - log L_kk with y = M (z - μ) (z (B, K) the measurements; covariance as in
    ``wu_loglik``); L_kk² multiplies vprod as in ``wu_loglik``. ``nu`` > 0: each step's
    conditional a Student-t instead, -(ν+1)/2 log(1 + y_k²/ν) plus its constant. Returns a failing
    trajectory's index, or -1."""
    B, K = mu.shape
    heavy = nu > 0.0
    a_t = -0.5 * (nu + 1.0)
    c_t = _t_const(nu) if heavy else 0.0
    ws = _tile_scratch(K, idx.shape[0])
    M, Ld = ws[2], ws[3]
    for b0 in range(0, B, T):
        nt = min(T, B - b0)
        bad = _tile_factor(cov, Z, w, idx, val, b0, nt, diag_add, ws)
        if bad >= 0:
            return b0 + bad
        for t in range(nt):
            b = b0 + t
            for k in range(K):
                y = 0.0
                for j in range(k + 1):
                    y += M[k, j, t] * (z[b, j] - mu[b, j])
                if heavy:
                    ll[b, k, 0] += a_t * math.log1p(y * y / nu) + c_t
                else:
                    ll[b, k, 0] += -0.5 * y * y
                _times_var(vprod, ll, b, k, Ld[k, t] * Ld[k, t])
    return -1


# Below this a probability is summed in log space: exp of it would lose digits as a subnormal.
_SAFE = math.exp(-650.0)
_UNDER = -745.2         # exp of anything below is 0.0 in double precision


@njit(**_NJIT)
def _exp(x):
    """exp(x) for x <= 0, without calling exp where the result is 0.0 anyway (confident steps)."""
    return math.exp(x) if x > _UNDER else 0.0


@njit(**_NJIT)
def recursion_mean(ll, vprod, logp0, n_per, out):
    """Eq. 24-26 in log space per trajectory, then the mean over each realization's n_per
    localization samples (Eq. 20): log likelihoods ll (C, B, K, S) - log(vprod (C, B, K))/2 ->
    out (B // n_per, K, C), log Σ_b P_b(c | H_k) over the realization's trajectories (the caller
    subtracts log n_per).

    Per step: h = ll + log P(c | H_{k-1}) normalised over c per dropout sample, then the mean over
    samples. The mean is taken on the shifted exponentials of the normalisation (one exp per
    entry instead of two) unless it is below e^-650, where it is redone in log space.
    """
    C, B, K, S = ll.shape
    R = B // n_per
    logp = np.empty(C)
    lv = np.empty(C)
    h = np.empty((C, S))
    e = np.empty((C, S))
    inv = np.empty(S)
    shift = np.empty(S)
    g = np.empty(S)
    lp = np.empty((n_per, K, C))
    logS = math.log(S)
    for i in range(R):
        for t in range(n_per):
            b = i * n_per + t
            for c in range(C):
                logp[c] = logp0[c]
            for k in range(K):
                for c in range(C):
                    lv[c] = logp[c] - 0.5 * math.log(vprod[c, b, k])
                for s in range(S):
                    m = -np.inf
                    for c in range(C):
                        v = ll[c, b, k, s] + lv[c]
                        h[c, s] = v
                        if v > m:
                            m = v
                    if not math.isfinite(m):
                        m = 0.0
                    tot = 0.0
                    for c in range(C):
                        x = _exp(h[c, s] - m)
                        e[c, s] = x
                        tot += x
                    inv[s] = 1.0 / tot
                    shift[s] = m
                for c in range(C):
                    acc = 0.0
                    for s in range(S):
                        acc += e[c, s] * inv[s]
                    if acc >= _SAFE:
                        logp[c] = math.log(acc) - logS
                        continue
                    # log route: h - log Σ_c exp(h), per sample, then logsumexp over samples
                    mx = -np.inf
                    for s in range(S):
                        g[s] = h[c, s] - (shift[s] - math.log(inv[s]))
                        if g[s] > mx:
                            mx = g[s]
                    if math.isfinite(mx):
                        acc = 0.0
                        for s in range(S):
                            acc += _exp(g[s] - mx)
                        logp[c] = math.log(acc) + mx - logS
                    else:
                        logp[c] = -np.inf
                for c in range(C):
                    lp[t, k, c] = logp[c]
        for k in range(K):          # log Σ over the realization's trajectories, shifted by the max
            for c in range(C):
                mx = -np.inf
                for t in range(n_per):
                    if lp[t, k, c] > mx:
                        mx = lp[t, k, c]
                if math.isfinite(mx):
                    acc = 0.0
                    for t in range(n_per):
                        acc += _exp(lp[t, k, c] - mx)
                    out[i, k, c] = math.log(acc) + mx
                else:
                    out[i, k, c] = -np.inf
    return out


@njit(**_NJIT)
def features(x, out):
    """``circle_basis.fill_features`` compiled: out (n, P) <- 1, cos θ, sin θ, cos 2θ, … of the
    unit vectors x (n, 2), by the same angle-addition recurrence."""
    n, P = out.shape
    for i in range(n):
        c1 = x[i, 0]
        s1 = x[i, 1]
        out[i, 0] = 1.0
        if P > 1:
            out[i, 1] = c1
            out[i, 2] = s1
        for k in range(2, (P - 1) // 2 + 1):
            c = out[i, 2 * k - 3]
            s = out[i, 2 * k - 2]
            out[i, 2 * k - 1] = c * c1 - s * s1
            out[i, 2 * k] = s * c1 + c * s1
    return out
