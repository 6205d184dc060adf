"""The batched fusion engine (docs/design.md §5): Model with Uncertainty, Model Based, Simple Bayes.

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

Batching: realizations × localization samples × classes × components in every array op. The
joint predictive comes from ``pipeline/method/engine.py`` (Fourier-feature GEMMs on the unit
circle, else kernel rows whitened by a triangular multiply); the K×K Cholesky factor, M's rows, y
and the q sums are computed in one batch-last pass (``_cond_stats``: every K×K step is a vector op
over all blocks' matrices); the recursion along the track is a loop over K vectorized over
everything else, in log space (logsumexp), so a confident posterior never becomes 0/0. The engine
before this one is kept as ``tests/reference_fusion.py``; the tests hold the two equal to 1e-9.

``engine_device`` runs the same blocks in torch float64 (``pipeline/method/engine_torch.py``) on a
GPU, or on the CPU for the tests.
"""
from __future__ import annotations

import math
import threading
from contextlib import contextmanager

import numpy as np

from pipeline.method import engine
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.gp import GPClassModels
from pipeline.method.names import METHOD_SHORT, MODEL_BASED, WITH_UNCERTAINTY

# Elements per working array in one block (a few such arrays live at once): ~2 MB each, about 180
# trajectories at 4 x 4 GPs, K = 9, N_s = 10. Blocks this size keep the basis GEMMs and Grams in
# the caches (measured faster than 4x larger blocks); more blocks cost little.
DEFAULT_BLOCK = 1 << 18

# Where the per-block work runs: "cpu" (numpy, pipeline/method/engine.py), "cuda" (torch float64 on
# the GPU, pipeline/method/engine_torch.py) or "torch-cpu" (the torch code on the CPU: the tests'
# and the bench's way to run it without a GPU). Set per thread by ``engine_device``.
_STATE = threading.local()
DEVICES = ("cpu", "cuda", "torch-cpu")


def current_device() -> str:
    return getattr(_STATE, "device", "cpu")


@contextmanager
def engine_device(device: str):
    """Run the fusion calls inside on ``device``: "cpu", "cuda", "torch-cpu", or "auto" (cuda when
    torch sees a GPU, else cpu). Results agree to rounding (tests/test_engine_torch.py)."""
    if device == "auto":
        from pipeline.infra.device import resolve_device
        device = resolve_device("auto")
    if device not in DEVICES:
        raise ValueError(f"engine_device: unknown device {device!r}; use auto, {', '.join(DEVICES)}")
    if device == "cuda":
        from pipeline.infra.device import resolve_device
        resolve_device("cuda")          # a clear error without a GPU
    old = current_device()
    _STATE.device = device
    try:
        yield device
    finally:
        _STATE.device = old


def _torch_device(device: str) -> str:
    return "cpu" if device == "torch-cpu" else device


# -- small numerics ------------------------------------------------------------------------------
def logsumexp(a: np.ndarray, axis: int, keepdims: bool = False) -> np.ndarray:
    """log Σ exp(a) along ``axis``; rows that are all -inf give -inf (never NaN)."""
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return out if keepdims else np.squeeze(out, axis=axis)


def log_prior(prior, C: int) -> np.ndarray:
    """Normalised log prior over C classes; None = uniform. Zero entries become -inf."""
    if prior is None:
        return np.full(C, -math.log(C))
    p = np.asarray(prior, dtype=float)
    if p.shape != (C,) or not np.all(np.isfinite(p)) or np.any(p < 0) or p.sum() <= 0:
        raise ValueError(f"prior must be {C} non-negative finite numbers with a positive sum, got {p.tolist()}")
    with np.errstate(divide="ignore"):
        return np.log(p / p.sum())


def _cholesky(cov: np.ndarray, models: GPClassModels) -> np.ndarray:
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        # Name the culprit: (class, component) axes are -4 and -3.
        ok = np.ones(cov.shape[-4:-2], dtype=bool)
        flat = cov.reshape((-1,) + cov.shape[-4:])
        for c in range(cov.shape[-4]):
            for f in range(cov.shape[-3]):
                try:
                    np.linalg.cholesky(flat[:, c, f])
                except np.linalg.LinAlgError:
                    ok[c, f] = False
        bad = [(models.classes[c], models.components[f]) for c, f in zip(*np.nonzero(~ok))]
        raise ValueError(f"joint predictive covariance is not positive definite for (class, component) {bad}: "
                         "white noise too small for the amplitude, or repeated inputs") from None


def _dropout_stats(dropout: np.ndarray, var_floor: float):
    """Per step and component: mean and population variance (ddof 0) floored at var_floor."""
    mu_z = dropout.mean(axis=-2)                                   # (..., K, F)
    v_z = np.maximum(dropout.var(axis=-2), var_floor)
    return mu_z, v_z


def _batch_last(mu: np.ndarray, cov: np.ndarray):
    """mu (b, C, F, K), cov (b, C, F, K, K) -> (K, nb) and (K, K, nb), nb = b·C·F: every small
    K×K operation below is then one vector op over nb contiguous numbers."""
    K = mu.shape[-1]
    return (np.ascontiguousarray(mu.reshape(-1, K).T),
            np.ascontiguousarray(cov.reshape(-1, K, K).transpose(1, 2, 0)))


def _cond_stats(A: np.ndarray, D: np.ndarray, V: np.ndarray | None):
    """Batch-last Cholesky ``A = L Lᵀ`` (K, K, nb) and ``M = L⁻¹``, reduced to what the recursion
    needs: L_kk, y = M D and q_k = Σ_{j<k} M_kj² V_j (each (K, nb); q None without V).
    None when some A is not positive definite (the caller names it). Only L's lower triangle is
    ever written or read."""
    K, nb = A.shape[0], A.shape[-1]
    L = engine.workspace("L", A.shape)
    for j in range(K):
        s = A[j, j] - np.einsum("kb,kb->b", L[j, :j], L[j, :j]) if j else A[0, 0].copy()
        if not np.all(s > 0):
            return None
        ljj = np.sqrt(s)
        L[j, j] = ljj
        if j + 1 < K:
            t = A[j + 1:, j] - np.einsum("ikb,kb->ib", L[j + 1:, :j], L[j, :j]) if j else A[1:, 0].copy()
            t /= ljj
            L[j + 1:, j] = t
    Ld = np.empty((K, nb))
    y = np.empty((K, nb))
    q = None if V is None else np.zeros((K, nb))
    M = engine.workspace("M", A.shape, zero=True)   # only its lower triangle is ever written: the rest stays 0
    for k in range(K):
        Ld[k] = L[k, k]
        inv = 1.0 / Ld[k]
        M[k, k] = inv
        if k:
            # M[k, :k] = -(L[k, :k] @ M[:k, :k]) / L_kk (forward substitution by rows)
            row = np.einsum("jb,jlb->lb", L[k, :k], M[:k, :k])
            row *= -inv
            M[k, :k] = row
            y[k] = np.einsum("jb,jb->b", row, D[:k]) + inv * D[k]
            if V is not None:
                q[k] = np.einsum("jb,jb->b", row * row, V[:k])
        else:
            y[0] = inv * D[0]
    return Ld, y, q


def _stats_or_raise(models, mu, cov, D, V):
    out = _cond_stats(*(_batch_last(mu, cov)[1:]), D, V)
    if out is None:
        _cholesky(cov, models)  # raises naming the (class, component)
        raise ValueError("joint predictive covariance is not positive definite")  # pragma: no cover
    return out


def _recursion_kfirst(ll: np.ndarray, logp0: np.ndarray) -> np.ndarray:
    """Eq. 24-26 in log space. ll (K, ..., C, S) per dropout sample -> log P(c|H_k) (..., K, C)."""
    K, *lead, C, S = ll.shape
    out = np.empty(tuple(lead) + (K, C))
    logp = np.broadcast_to(logp0, tuple(lead) + (C,))
    for k in range(K):
        h = ll[k] + logp[..., None]                                # (..., C, S)
        h -= logsumexp(h, axis=-2, keepdims=True)
        logp = logsumexp(h, axis=-1) - math.log(S)
        out[..., k, :] = logp
    return out


# -- Model with Uncertainty ----------------------------------------------------------------------
def _mwu_block(models: GPClassModels, X: np.ndarray, mu_z: np.ndarray, v_z: np.ndarray, samples: np.ndarray,
               logp0: np.ndarray) -> np.ndarray:
    """X (r, n, K, d) localization samples; per realization the dropout means and floored
    variances mu_z, v_z (r, K, F) and the samples (r, K, S, F) -> per-sample log posteriors (r, n, K, C).

    Per step k, class and component (module docstring): conditional mean μ_z,k - L_kk y_k and
    variance L_kk² (1 + q_k) of each dropout sample, y = M (μ_z - μ), q_k = Σ_{j<k} M_kj² v_j.
    """
    r, n, K, d = X.shape
    C, F = models.n_classes, models.n_components
    S = samples.shape[2]
    mu, cov = engine.predictive(models, X.reshape(r * n, K, d))
    mu5 = mu.reshape(r, n, C, F, K)
    mzt = np.transpose(mu_z, (1, 0, 2))[:, :, None, None, :]        # (K, r, 1, 1, F)
    D = (mzt - np.moveaxis(mu5, -1, 0)).reshape(K, -1)              # (K, nb), nb = (r, n, C, F)
    V = np.broadcast_to(np.transpose(v_z, (1, 0, 2))[:, :, None, None, :], (K, r, n, C, F)).reshape(K, -1)
    Ld, y, q = _stats_or_raise(models, mu, cov, D, V)
    del cov
    var = Ld * Ld
    var *= 1.0 + q                                                  # (K, nb)
    cmean = np.broadcast_to(mzt, (K, r, n, C, F)).reshape(K, -1) - Ld * y
    # Gaussian log density of every dropout sample s_k, summed over components (Eq. 17); the
    # -log(2π)/2 per component is the same for every class and cancels in the normalisation.
    w = (1.0 / np.sqrt(var)).reshape(K, r, n, C, F)
    cmean = cmean.reshape(K, r, n, C, F)
    s = np.transpose(samples, (1, 0, 3, 2))                         # (K, r, F, S)
    ll = np.zeros((K, r, n, C, S))
    for f in range(F):
        t = s[:, :, None, None, f, :] - cmean[..., f, None]         # (K, r, n, C, S)
        t *= w[..., f, None]
        t *= t
        ll += t
    ll *= -0.5
    ll += (np.log(w).sum(axis=-1))[..., None]                       # -½ Σ_f log var
    return _recursion_kfirst(ll, logp0)


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

    mu_z, v_z = _dropout_stats(Z, var_floor)                       # (R, K, F), once per call

    device = current_device()

    def work(span):
        r0, r1, x0, x1 = span
        if device != "cpu":
            from pipeline.method import engine_torch
            return engine_torch.mwu_block(models, _torch_device(device), X[r0:r1, x0:x1], mu_z[r0:r1],
                                          v_z[r0:r1], Z[r0:r1], logp0)
        return logsumexp(_mwu_block(models, X[r0:r1, x0:x1], mu_z[r0:r1], v_z[r0:r1], Z[r0:r1], logp0), axis=1)

    for (r0, r1, _, _), lse in _run_blocks(models, work, spans, threads, progress, METHOD_SHORT[WITH_UNCERTAINTY]):
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

    device = current_device()

    def work(span):
        r0, r1 = span[:2]
        b = r1 - r0
        if device != "cpu":
            from pipeline.method import engine_torch
            return engine_torch.mb_block(models, _torch_device(device), X[r0:r1], Z[r0:r1], logp0)
        mu, cov = engine.predictive(models, X[r0:r1])               # (b, C, F, K[, K])
        resid = np.swapaxes(Z[r0:r1], -1, -2)[:, None] - mu         # z - μ
        D = np.ascontiguousarray(np.moveaxis(resid, -1, 0).reshape(K, -1))
        Ld, y, _ = _stats_or_raise(models, mu, cov, D, None)       # y: whitened innovations
        ll = (-0.5 * y * y - np.log(Ld)).reshape(K, b, C, F).sum(axis=-1)   # chain rule per step
        return _recursion_kfirst(ll[..., None], logp0)

    spans = _blocks(R, 1, _per_sample_cost(models, K, 1), block)
    for (r0, r1, _, _), lp in _run_blocks(models, work, spans, threads, progress, METHOD_SHORT[MODEL_BASED]):
        out[r0:r1] = lp
    out = out - logsumexp(out, axis=-1, keepdims=True)
    out = out if return_log else np.exp(out)
    return out[0] if single else out


# -- Simple Bayes --------------------------------------------------------------------------------
def simple_bayes(scores, *, prior=None, return_log: bool = False) -> np.ndarray:
    """Simple Bayes (Patten et al.): P(c|H_k) ∝ P(c|H_{k-1}) s_k[c]. scores (K, C) or (R, K, C),
    one score component per candidate class. Zero scores are floored at the smallest normal
    float so that a class can lose but never turn the posterior into 0/0."""
    s = np.asarray(scores, dtype=float)
    single = s.ndim == 2
    if single:
        s = s[None]
    if s.ndim != 3 or s.shape[-1] < 1:
        raise ValueError(f"simple_bayes: scores must be (K, C) or (R, K, C), got {np.shape(scores)}")
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError("simple_bayes: scores must be finite and non-negative")
    logp0 = log_prior(prior, s.shape[-1])
    logs = np.log(np.maximum(s, np.finfo(float).tiny))
    cum = np.cumsum(logs, axis=1) + logp0
    out = cum - logsumexp(cum, axis=-1, keepdims=True)
    out = out if return_log else np.exp(out)
    return out[0] if single else out


# -- chunking --------------------------------------------------------------------------------------
def _per_sample_cost(models: GPClassModels, K: int, S: int) -> int:
    """Largest working-array size (elements) per trajectory."""
    C, F = models.n_classes, models.n_components
    n_train = max(len(x) for x in models.X)
    return max(K * n_train, C * F * K * K, C * F * K * S)


def _blocks(R: int, Nx: int, per_sample: int, block: int) -> list[tuple[int, int, int, int]]:
    """(r0, r1, x0, x1) spans: several whole realizations per block, or slices of one realization's
    localization samples when a single realization is too big."""
    per = max(1, block // max(per_sample, 1))
    if per >= Nx:
        step = max(1, per // Nx)
        return [(r0, min(R, r0 + step), 0, Nx) for r0 in range(0, R, step)]
    return [(r, r + 1, x0, min(Nx, x0 + per)) for r in range(R) for x0 in range(0, Nx, per)]


def _run_blocks(models: GPClassModels, work, spans, threads: int | None, progress: bool, desc: str,
                prepare=engine.plan):
    """Yield (span, work(span)) in order, blocks spread over ``threads`` worker threads.
    ``prepare(models)`` runs first, so that shared state the workers read is built once.

    BLAS is held to one thread meanwhile: the blocks are small, and BLAS's own threads on small
    products cost more in synchronisation than they gain (badly so on a busy machine); numpy and
    BLAS release the GIL, so parallel blocks use the cores instead.
    """
    from concurrent.futures import ThreadPoolExecutor
    from contextlib import nullcontext

    from pipeline.infra.device import available_cores
    from pipeline.infra.progress import bar as progress_bar

    n = max(1, min(int(threads or available_cores()), len(spans)))
    prepare(models)  # the shared routes and factors, built before any worker reads them
    bar = progress_bar(total=len(spans), desc=desc, unit="block", leave=False,
                       enabled=progress and len(spans) >= 2)
    try:  # installed with scikit-learn
        from threadpoolctl import threadpool_limits
        one_blas_thread = threadpool_limits(limits=1, user_api="blas")
    except ImportError:  # pragma: no cover - same results, only slower
        one_blas_thread = nullcontext()
    with one_blas_thread:
        if n == 1:
            for span in spans:
                yield span, work(span)
                bar.update(1)
        else:
            with ThreadPoolExecutor(max_workers=n) as pool:
                # A bounded window of blocks in flight keeps memory at ~2n blocks.
                pending = []
                it = iter(spans)
                for span in it:
                    pending.append((span, pool.submit(work, span)))
                    if len(pending) >= 2 * n:
                        break
                while pending:
                    span, fut = pending.pop(0)
                    res = fut.result()
                    nxt = next(it, None)
                    if nxt is not None:
                        pending.append((nxt, pool.submit(work, nxt)))
                    yield span, res
                    bar.update(1)
    bar.close()
