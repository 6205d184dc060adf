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

Batching: realizations × localization samples per block; per (class, component) GP the joint
predictive comes from ``pipeline/method/engine.py`` (on the unit circle as Fourier features, in
the diagonal or sparse form a turntable's evenly spaced training views allow, else kernel rows
whitened by a triangular multiply), and the compiled kernels of ``pipeline/method/kernels.py``
do the rest per trajectory: the K×K Cholesky factor, M's rows, y and the q sums, the Gaussian
log densities of the dropout samples, and the recursion along the track in log space
(logsumexp), so a confident posterior never becomes 0/0. The engine before this one is kept as
``tests/support/reference_fusion.py``; the tests hold the two equal to 1e-9.

``engine_device`` runs the same blocks in torch float64 (``pipeline/method/engine_torch.py``) on a
GPU, or on the CPU for the tests.
"""
from __future__ import annotations

import math
import threading
from contextlib import contextmanager

import numpy as np

from pipeline.method import engine
from pipeline.method.gp import GPClassModels
from pipeline.infra.device import resolve_device
from pipeline.method import engine_torch   # torch itself is imported inside it, on use
from pipeline.infra.device import available_cores
from pipeline.infra.progress import bar as progress_bar

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
        device = resolve_device("auto")
    if device not in DEVICES:
        raise ValueError(f"engine_device: unknown device {device!r}; use auto, {', '.join(DEVICES)}")
    if device == "cuda":
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


def _check_nu(who: str, nu) -> float:
    """ν as the kernels take it: 0.0 for the Gaussian (None), else a finite number > 0."""
    if nu is None:
        return 0.0
    if not (isinstance(nu, (int, float, np.floating)) and math.isfinite(nu) and nu > 0):
        raise ValueError(f"{who}: nu (Student-t degrees of freedom) must be a finite number > 0 or None, got {nu!r}")
    return float(nu)


def _dropout_stats(dropout: np.ndarray, var_floor: float):
    """Per step and component: mean and population variance (ddof 0) floored at var_floor."""
    mu_z = dropout.mean(axis=-2)                                   # (..., K, F)
    v_z = np.maximum(dropout.var(axis=-2), var_floor)
    return mu_z, v_z


# -- Model with Uncertainty ----------------------------------------------------------------------
def _mwu_block(models: GPClassModels, X: np.ndarray, mu_z: np.ndarray, v_z: np.ndarray, samples: np.ndarray,
               logp0: np.ndarray, nu: float = 0.0) -> np.ndarray:
    """X (r, n, K, d) localization samples; per realization the dropout means and floored
    variances mu_z, v_z (r, K, F) and the samples (r, K, S, F) -> per realization the log of the
    summed posteriors over its n samples (r, K, C) (the caller subtracts log n).

    Per GP (``engine.per_gp``) the compiled kernel adds each trajectory's Gaussian log densities of
    the dropout samples (Eq. 17, module docstring: mean μ_z,k - L_kk y_k, variance L_kk² (1 + q_k));
    the -log(2π)/2 per component is the same for every class and cancels in the normalisation.
    """
    from pipeline.method import kernels   # heavy: numba

    r, n, K, d = X.shape
    C = models.n_classes
    S = samples.shape[2]
    mz = np.ascontiguousarray(np.moveaxis(mu_z, -1, 0))             # (F, r, K)
    vz = np.ascontiguousarray(np.moveaxis(v_z, -1, 0))
    smp = np.ascontiguousarray(np.moveaxis(samples, -1, 0))   # (F, r, K, S)
    ll = np.zeros((C, r * n, K, S))
    vprod = np.ones((C, r * n, K))
    for c, f, mu, cov, Zg, w, idx, val, add in engine.per_gp(models, X.reshape(r * n, K, d)):
        if kernels.wu_loglik(cov, Zg, w, idx, val, add, mu, mz[f], vz[f], smp[f], n, ll[c], vprod[c], nu) >= 0:
            engine.not_positive_definite(models, [(c, f)])
    return kernels.recursion_mean(ll, vprod, logp0, n, np.empty((r, K, C)))


def fuse_with_uncertainty(models: GPClassModels, inputs, dropout, *, prior=None, var_floor: float = 1e-6,
                          return_log: bool = False, block: int = DEFAULT_BLOCK,
                          threads: int | None = None, progress: bool = True, nu: float | None = None) -> np.ndarray:
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
    nu : None (the paper's Gaussian) or ν > 0: each step's conditional a Student-t with the same
        location and squared scale (``pipeline.method.student_t``).

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
    nu = _check_nu("fuse_with_uncertainty", nu)
    logp0 = log_prior(prior, C)
    acc = np.full((R, K, C), -np.inf)
    spans = _blocks(R, Nx, _per_sample_cost(models, K, Z.shape[2]), block)

    mu_z, v_z = _dropout_stats(Z, var_floor)                       # (R, K, F), once per call

    device = current_device()

    def work(span):
        r0, r1, x0, x1 = span
        if device != "cpu":
            return engine_torch.mwu_block(models, _torch_device(device), X[r0:r1, x0:x1], mu_z[r0:r1],
                                          v_z[r0:r1], Z[r0:r1], logp0, nu)
        return _mwu_block(models, X[r0:r1, x0:x1], mu_z[r0:r1], v_z[r0:r1], Z[r0:r1], logp0, nu)

    for (r0, r1, _, _), lse in _run_blocks(models, work, spans, threads, progress, "With Uncertainty"):
        np.logaddexp(acc[r0:r1], lse, out=acc[r0:r1])
    acc -= math.log(Nx)
    acc = acc - logsumexp(acc, axis=-1, keepdims=True)  # exact already; removes rounding drift
    out = acc if return_log else np.exp(acc)
    return out[0] if single else out


# -- Model Based ---------------------------------------------------------------------------------
def fuse_model_based(models: GPClassModels, inputs, measurements, *, prior=None, return_log: bool = False,
                     block: int = DEFAULT_BLOCK, threads: int | None = None,
                     progress: bool = True, nu: float | None = None) -> np.ndarray:
    """Model Based (Teacy et al.): one pose-estimate trajectory, one measurement per step.

    inputs (K, d) or (R, K, d); measurements (K, F) or (R, K, F) (e.g. the mean of each dropout
    set). P(z_k | c, z_past) = Π_f N(z_k; μ_k + Ω(z_past - μ_past), Σ_{k|past}); with ``nu``, each
    factor a Student-t of ν degrees of freedom with that location and squared scale.
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
    nu = _check_nu("fuse_model_based", nu)
    logp0 = log_prior(prior, C)
    out = np.empty((R, K, C))

    device = current_device()

    def work(span):
        r0, r1 = span[:2]
        b = r1 - r0
        if device != "cpu":
            return engine_torch.mb_block(models, _torch_device(device), X[r0:r1], Z[r0:r1], logp0, nu)
        from pipeline.method import kernels   # heavy: numba

        z = np.ascontiguousarray(np.moveaxis(Z[r0:r1], -1, 0))      # (F, b, K)
        ll = np.zeros((C, b, K, 1))
        vprod = np.ones((C, b, K))
        for c, f, mu, cov, Zg, w, idx, val, add in engine.per_gp(models, X[r0:r1]):
            if kernels.mb_loglik(cov, Zg, w, idx, val, add, mu, z[f], ll[c], vprod[c], nu) >= 0:
                engine.not_positive_definite(models, [(c, f)])
        return kernels.recursion_mean(ll, vprod, logp0, 1, np.empty((b, K, C)))

    spans = _blocks(R, 1, _per_sample_cost(models, K, 1), block)
    for (r0, r1, _, _), lp in _run_blocks(models, work, spans, threads, progress, "Model Based"):
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
    return max(K * n_train, K * engine.plan(models).P_max, C * F * K * K, C * F * K * S)


def _blocks(R: int, Nx: int, per_sample: int, block: int) -> list[tuple[int, int, int, int]]:
    """(r0, r1, x0, x1) spans: several whole realizations per block, or slices of one realization's
    localization samples when a single realization is too big."""
    per = max(1, block // max(per_sample, 1))
    if per >= Nx:
        step = max(1, per // Nx)
        return [(r0, min(R, r0 + step), 0, Nx) for r0 in range(0, R, step)]
    return [(r, r + 1, x0, min(Nx, x0 + per)) for r in range(R) for x0 in range(0, Nx, per)]


_CONTROLLERS: dict = {}


def _blas_controller():
    """A threadpoolctl controller of the loaded BLAS libraries, made once per set of loaded
    native packages (making one scans every loaded library: 5-13 ms, paid per call before)."""
    import sys

    try:  # installed with scikit-learn
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - same results, only slower
        return None
    key = tuple(m in sys.modules for m in ("numpy", "scipy.linalg", "sklearn", "torch"))
    ctl = _CONTROLLERS.get(key)
    if ctl is None:
        ctl = _CONTROLLERS[key] = ThreadpoolController()
    return ctl


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

    n = max(1, min(int(threads or available_cores()), len(spans)))
    prepare(models)  # the shared routes and factors, built before any worker reads them
    bar = progress_bar(total=len(spans), desc=desc, unit="block", leave=False,
                       enabled=progress and len(spans) >= 2)
    controller = _blas_controller()
    one_blas_thread = nullcontext() if controller is None else controller.limit(limits=1, user_api="blas")
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
