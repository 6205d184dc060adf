"""The reference fusion engine: the product's engine before the circle-basis route
(pipeline/method/engine.py), its per-block kernels kept verbatim for the equality tests and the
bench ratio; the helpers around them (numerics, chunking, threads) are the product's own.
Its GP predictive is ``GPClassModels.predict`` (one triangular solve per test row).

Batched fusion (docs/design.md §5): Model with Uncertainty, Model Based, Simple Bayes.

All three return the class posterior after every step of the track.

How a whole track costs O(K³) per localization sample instead of O(K⁴): for one trajectory and
one (class, component) let ``Σ = L Lᵀ`` be the K×K joint predictive covariance (white noise
included) and ``M = L⁻¹``. For the prefix 0..k-1, ``Σ_past⁻¹`` involves only the leading k×k
blocks of L and M, which gives for every k at once

    Σ_{k|past} = L_kk²,    Ω_k = Σ_{k,past} Σ_past⁻¹ = -L_kk · M[k, :k].

With ``d = μ_z - μ`` (past dropout means minus predictive means) and ``y = M d``:
``Ω_k d_past = d_k - L_kk y_k``, so the conditional mean of the paper's closed form
``N(s_k; μ_k + Ω(μ_z - μ_past), Σ_{k|past} + Ω diag(v_z) Ωᵀ)`` is ``μ_z,k - L_kk y_k`` and its
variance is ``L_kk² (1 + Σ_{j<k} M_kj² v_j)``. Model Based is the same with the measurements in
place of μ_z and no v_z term (the chain rule of one Gaussian).

Batching: realizations × localization samples × classes × components in every array op; the
train-test kernels are big GEMMs (``GPClassModels.predict``); the recursion along the track is a
loop over K vectorized over everything else, in log space (logsumexp), so a confident posterior
never becomes 0/0.
"""
from __future__ import annotations

import math

import numpy as np

# The helpers that are not the engine (numerics, chunking, threads, Simple Bayes) are the product's own.
from pipeline.method.engine import named_cholesky as _cholesky
from pipeline.method.fusion import (_blocks, _dropout_stats, _per_sample_cost, _run_blocks,  # noqa: F401
                                    log_prior, logsumexp, simple_bayes)
from pipeline.method.gp import GPClassModels

# Elements per working array in one block (a few such arrays live at once): ~8 MB each. Blocks
# this size keep the train-test kernel passes near the caches; more blocks cost little.
DEFAULT_BLOCK = 1 << 20


# -- small numerics ------------------------------------------------------------------------------
def tri_inverse(L: np.ndarray) -> np.ndarray:
    """Inverse of lower-triangular matrices (..., K, K) by forward substitution, vectorized over
    the batch (K steps; exactly triangular output)."""
    K = L.shape[-1]
    M = np.zeros_like(L)
    inv_diag = 1.0 / np.diagonal(L, axis1=-2, axis2=-1)
    for k in range(K):
        if k:
            # M[k, :k] = -(L[k, :k] @ M[:k, :k]) / L_kk
            M[..., k, :k] = -np.einsum("...j,...jl->...l", L[..., k, :k], M[..., :k, :k]) * inv_diag[..., k, None]
        M[..., k, k] = inv_diag[..., k]
    return M


def track_factors(models: GPClassModels, X: np.ndarray):
    """mu (B, C, F, K), Cholesky factor L and its inverse M (B, C, F, K, K) for trajectories X (B, K, d)."""
    mu, cov = models.predict(X)
    L = _cholesky(cov, models)
    del cov
    return mu, L, tri_inverse(L)


def _recursion(ll: np.ndarray, logp0: np.ndarray) -> np.ndarray:
    """Eq. 24-26 in log space. ll (..., C, K, S) per dropout sample -> log P(c|H_k) (..., K, C).

    For each step: h_c(s) = P(s|c, past) P(c|H_{k-1}) normalised over c, then P(c|H_k) = mean_s h_c(s).
    """
    *lead, C, K, S = ll.shape
    out = np.empty(tuple(lead) + (K, C))
    logp = np.broadcast_to(logp0, tuple(lead) + (C,))
    for k in range(K):
        h = ll[..., k, :] + logp[..., None]                        # (..., C, S)
        h = h - logsumexp(h, axis=-2, keepdims=True)
        logp = logsumexp(h, axis=-1) - math.log(S)
        out[..., k, :] = logp
    return out


# -- Model with Uncertainty ----------------------------------------------------------------------
def _mwu_block(models: GPClassModels, X: np.ndarray, dropout: np.ndarray, logp0: np.ndarray,
               var_floor: float) -> np.ndarray:
    """X (r, n, K, d) localization samples, dropout (r, K, S, F) -> per-sample log posteriors (r, n, K, C)."""
    r, n, K, d = X.shape
    C, F = models.n_classes, models.n_components
    mu, L, M = track_factors(models, X.reshape(r * n, K, d))
    shape = (r, n, C, F, K)
    mu, L, M = mu.reshape(shape), L.reshape(shape + (K,)), M.reshape(shape + (K,))
    mu_z, v_z = _dropout_stats(dropout, var_floor)                 # (r, K, F)
    mu_zt = np.swapaxes(mu_z, -1, -2)[:, None, None]               # (r, 1, 1, F, K)
    v_zt = np.swapaxes(v_z, -1, -2)[:, None, None, :, None, :]     # (r, 1, 1, F, 1, K)
    y = np.einsum("...kj,...j->...k", M, mu_zt - mu)               # M (μ_z - μ)
    M *= M                                                          # M∘M, only its strict lower part is used
    idx = np.arange(K)
    M[..., idx, idx] = 0.0
    q = np.einsum("...kj,...j->...k", M, v_zt[..., 0, :])          # Σ_{j<k} M_kj² v_j
    del M
    Ld = np.diagonal(L, axis1=-2, axis2=-1)                         # (r, n, C, F, K)
    var = Ld * Ld * (1.0 + q)
    cmean = mu_zt - Ld * y
    del L, y, q
    # Gaussian log density of every dropout sample s_k, summed over components (Eq. 17); the
    # -log(2π)/2 per component is the same for every class and cancels in the normalisation.
    s = np.moveaxis(dropout, -1, -3)[:, None, None]                 # (r, 1, 1, F, K, S)
    resid = s - cmean[..., None]                                    # (r, n, C, F, K, S)
    resid *= resid
    resid /= var[..., None]
    ll = -0.5 * resid.sum(axis=-3) - 0.5 * np.log(var).sum(axis=-2)[..., None]   # (r, n, C, K, S)
    return _recursion(ll, logp0)


def fuse_with_uncertainty(models: GPClassModels, inputs, dropout, *, prior=None, var_floor: float = 1e-6,
                          return_log: bool = False, block: int = DEFAULT_BLOCK,
                          threads: int | None = None, progress: bool = True) -> np.ndarray:
    """Model with Uncertainty (the paper's Algorithm 1) after every step of the track.

    Parameters
    ----------
    models : the class GPs (C classes × F components).
    inputs : (N_x, K, d) or (R, N_x, K, d) GP inputs (already relative / unit-circle) of the
        localization samples: N_x trajectories per realization.
    dropout : (K, N_s, F) or (R, K, N_s, F) dropout sample sets per step, at the models' components.
    prior : (C,) prior over classes (default uniform).
    var_floor : floor on the population variance of each past step's dropout samples.
    return_log : return log posteriors (finite even where probabilities underflow).
    block, threads, progress : working-set size per block (array elements), worker threads
        (default: all cores), progress bar over blocks. They change speed, not results.

    Returns (K, C) or (R, K, C): P(c | H_k), the mean over localization samples of each sample's
    own recursion (Eq. 20, 42).
    """
    X = np.asarray(inputs, dtype=float)
    Z = np.asarray(dropout, dtype=float)
    single = X.ndim == 3
    if single:
        X = X[None]
        Z = Z[None] if Z.ndim == 3 else Z
    C, F, d = models.n_classes, models.n_components, models.input_dim
    if X.ndim != 4 or X.shape[-1] != d:
        raise ValueError(f"fuse_with_uncertainty: inputs must be (N_x, K, {d}) or (R, N_x, K, {d}), "
                         f"got {np.shape(inputs)}")
    R, Nx, K, _ = X.shape
    if Z.ndim != 4 or Z.shape[0] != R or Z.shape[1] != K or Z.shape[3] != F or Z.shape[2] < 1:
        raise ValueError(f"fuse_with_uncertainty: dropout must be ({K}, N_s, {F}) or ({R}, {K}, N_s, {F}) "
                         f"to match inputs {X.shape}, got {np.shape(dropout)}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Z))):
        raise ValueError("fuse_with_uncertainty: inputs or dropout samples contain NaN or infinite values")
    if var_floor < 0:
        raise ValueError(f"fuse_with_uncertainty: var_floor must be >= 0, got {var_floor}")
    logp0 = log_prior(prior, C)
    acc = np.full((R, K, C), -np.inf)
    spans = _blocks(R, Nx, _per_sample_cost(models, K, Z.shape[2]), block)

    def work(span):
        r0, r1, x0, x1 = span
        return logsumexp(_mwu_block(models, X[r0:r1, x0:x1], Z[r0:r1], logp0, var_floor), axis=1)

    for (r0, r1, _, _), lse in _run_blocks(models, work, spans, threads, progress, "With Uncertainty",
                                                   prepare=GPClassModels.factors):
        np.logaddexp(acc[r0:r1], lse, out=acc[r0:r1])
    acc -= math.log(Nx)
    acc = acc - logsumexp(acc, axis=-1, keepdims=True)  # exact already; removes rounding drift
    out = acc if return_log else np.exp(acc)
    return out[0] if single else out


# -- Model Based ---------------------------------------------------------------------------------
def fuse_model_based(models: GPClassModels, inputs, measurements, *, prior=None, return_log: bool = False,
                     block: int = DEFAULT_BLOCK, threads: int | None = None,
                     progress: bool = True) -> np.ndarray:
    """Model Based (Teacy et al.): one pose-estimate trajectory, one measurement per step.

    inputs (K, d) or (R, K, d); measurements (K, F) or (R, K, F) (e.g. the mean of each dropout
    set). P(z_k | c, z_past) = Π_f N(z_k; μ_k + Ω(z_past - μ_past), Σ_{k|past}).
    Returns (K, C) or (R, K, C).
    """
    X = np.asarray(inputs, dtype=float)
    Z = np.asarray(measurements, dtype=float)
    single = X.ndim == 2
    if single:
        X, Z = X[None], Z[None]
    C, F, d = models.n_classes, models.n_components, models.input_dim
    if X.ndim != 3 or X.shape[-1] != d:
        raise ValueError(f"fuse_model_based: inputs must be (K, {d}) or (R, K, {d}), got {np.shape(inputs)}")
    R, K, _ = X.shape
    if Z.shape != (R, K, F):
        raise ValueError(f"fuse_model_based: measurements must be ({K}, {F}) or ({R}, {K}, {F}), "
                         f"got {np.shape(measurements)}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Z))):
        raise ValueError("fuse_model_based: inputs or measurements contain NaN or infinite values")
    logp0 = log_prior(prior, C)
    out = np.empty((R, K, C))

    def work(span):
        r0, r1 = span[:2]
        mu, L, M = track_factors(models, X[r0:r1])                  # (b, C, F, K[, K])
        resid = np.swapaxes(Z[r0:r1], -1, -2)[:, None] - mu         # z - μ
        y = np.einsum("...kj,...j->...k", M, resid)                 # whitened innovations
        Ld = np.diagonal(L, axis1=-2, axis2=-1)
        ll = (-0.5 * y * y - np.log(Ld)).sum(axis=-2)               # (b, C, K): chain rule per step
        return _recursion(ll[..., None], logp0)

    spans = _blocks(R, 1, _per_sample_cost(models, K, 1), block)
    for (r0, r1, _, _), lp in _run_blocks(models, work, spans, threads, progress, "Model Based",
                                                  prepare=GPClassModels.factors):
        out[r0:r1] = lp
    out = out - logsumexp(out, axis=-1, keepdims=True)
    out = out if return_log else np.exp(out)
    return out[0] if single else out
