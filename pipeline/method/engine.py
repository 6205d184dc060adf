"""The joint predictive per trajectory for the fusion engine, by the cheapest exact route per GP.

Two routes per (class, component), chosen once per model bank (``plan``):

* **basis** (``pipeline/method/circle_basis.py``): unit-circle inputs, P = 2M + 1 Fourier
  features; per point one row of a (rows × P)·(P × P) GEMM, no exp. Taken when the class's
  training inputs are unit vectors and P ≤ N (the training views).
* **exact**: the reference route of ``GPClassModels.predict`` (kernel rows against the N training
  views, whitened by the training Cholesky factor), with L⁻¹ precomputed so that the whitening is a
  triangular *multiply* (TRMM, GEMM speed) instead of a triangular solve.

A call uses the basis route of a GP only when every test input of the call is a unit vector to
``UNIT_TOL``; otherwise that call takes the exact route for every GP.
"""
from __future__ import annotations

import threading
import weakref

import numpy as np

from pipeline.method import circle_basis as cb
from pipeline.method.gp import GPClassModels, predictive_covariance
from pipeline.method.gp_instance import instance_term

_PLANS: "weakref.WeakKeyDictionary[GPClassModels, Plan]" = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()
_BASIS: dict[str, cb.BasisGP | None] = {}
_BASIS_MAX = 8192


def _basis_gp(models: GPClassModels, c: int, f: int) -> cb.BasisGP | None:
    """``circle_basis.build`` for GP (c, f), cached by its content (``GPClassModels.digest``)."""
    x, y = models.X[c], np.ascontiguousarray(models.Y[c][f])
    key = models.digest(c, f, trained_only=True)
    with _LOCK:
        if key in _BASIS:
            return _BASIS[key]
    g = cb.build(x, y, models.mean[c, f], models.amplitude[c, f], models.length_scale[c, f], models.noise[c, f])
    with _LOCK:
        if len(_BASIS) >= _BASIS_MAX:
            _BASIS.clear()
        _BASIS[key] = g
    return g


def _cheaper(g: cb.BasisGP, N: int) -> bool:
    """Whether the basis route beats the exact one (N training views): per point the dense basis
    costs P² (TRMM), the sparse form r·P, the exact route N² plus N kernel entries."""
    if g.q2 is not None or g.idx is not None:
        return g.P * g.idx.shape[1] <= N * N // 2
    return g.P <= N


class Plan:
    """Per-GP route and factors of one model bank (built once, shared by worker threads). Basis
    factors come from a cache keyed by the GP's content, so the per-cell ``subset`` of a bank
    reuses them; the exact route's factors are made on first use."""

    def __init__(self, models: GPClassModels, basis: bool = True):
        self.models = models
        C, F = models.n_classes, models.n_components
        self.basis: list[list[cb.BasisGP | None]] = [[None] * F for _ in range(C)]
        self._linv: dict[tuple[int, int], np.ndarray] = {}
        on_circle = models.input_dim == 2
        for c in range(C):
            N = len(models.X[c])
            unit = on_circle and cb.unit_error(models.X[c]) <= cb.UNIT_TOL
            for f in range(F):
                # A GP with an instance term (gp_instance.py) has a training covariance that is not
                # one stationary kernel: the exact route only.
                g = _basis_gp(models, c, f) if basis and unit and instance_term(models, c, f) is None else None
                self.basis[c][f] = g if g is not None and _cheaper(g, N) else None
        self.P_max = max([g.P for row in self.basis for g in row if g is not None] or [0])
        self.members = [(c, f) for c, row in enumerate(self.basis) for f, g in enumerate(row) if g is not None]
        self.q_fortran = [self.basis[c][f].QF for c, f in self.members]
        self.ones = np.ones(self.P_max)
        self.no_idx, self.no_val = np.zeros((0, 1), dtype=np.int64), np.zeros((0, 1))
        self.wbar = np.zeros((self.P_max, len(self.members)))
        for i, (c, f) in enumerate(self.members):
            g = self.basis[c][f]
            self.wbar[:g.P, i] = g.wbar

    def linv(self, c: int, f: int) -> np.ndarray:
        """L⁻¹ (Fortran order) of GP (c, f)'s training Cholesky factor, for the exact route."""
        out = self._linv.get((c, f))
        if out is None:
            from scipy.linalg import solve_triangular

            L = self.models.factors()[c].L[f]
            out = np.asfortranarray(solve_triangular(L, np.eye(len(L)), lower=True))
            with _LOCK:
                self._linv[(c, f)] = out
        return out

    def routes(self) -> dict:
        """{'basis': n, 'diagonal': n (of them), 'exact': n, 'P': [...]} for logs and the bench."""
        gs = [g for row in self.basis for g in row if g is not None]
        return {"basis": len(gs), "diagonal": sum(g.q2 is not None for g in gs),
                "exact": sum(g is None for row in self.basis for g in row), "P": [g.P for g in gs]}


_WORK = threading.local()
_NONE = np.empty((0, 0, 0))   # the unused one of (S, Z) in per_gp's items
_NO_W = np.empty(0)


def workspace(name: str, shape: tuple) -> np.ndarray:
    """A per-thread scratch array reused from block to block (fresh large arrays cost page
    faults on every block); its contents are whatever the last user left. Not for results handed
    back."""
    cache = getattr(_WORK, "arrays", None)
    if cache is None:
        cache = _WORK.arrays = {}
    key = (name, tuple(shape))
    a = cache.get(key)
    if a is None:
        if len(cache) > 32:
            cache.clear()
        a = cache[key] = np.empty(shape)
    return a


def plan(models: GPClassModels) -> Plan:
    with _LOCK:
        p = _PLANS.get(models)
    if p is None:
        p = Plan(models)
        with _LOCK:
            p = _PLANS.setdefault(models, p)
    return p


def predictive(models: GPClassModels, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """mu (B, C, F, K) and cov (B, C, F, K, K) (white noise included) for trajectories X (B, K, d):
    ``GPClassModels.predict`` to rounding, faster."""
    X = np.ascontiguousarray(X, dtype=float)
    B, K, _ = X.shape
    mu = np.empty((B, models.n_classes, models.n_components, K))
    cov = np.empty((B, models.n_classes, models.n_components, K, K))
    diag = np.arange(K)
    for c, f, m, S, Z, w, idx, val, add in per_gp(models, X):
        mu[:, c, f] = m
        if len(idx):   # sparse form: z_p = Σ_t val[p, t] φ_idx[p, t]
            Zq = np.einsum("bkpt,pt->bkp", Z[..., idx], val)
            cov[:, c, f] = np.matmul(Zq, Zq.transpose(0, 2, 1))
        elif len(w):
            Zp = Z[..., :len(w)]
            cov[:, c, f] = np.matmul(Zp * w, Zp.transpose(0, 2, 1))
        else:
            cov[:, c, f] = S
        cov[:, c, f, diag, diag] += add
    return mu, cov


def per_gp(models: GPClassModels, X: np.ndarray):
    """Yield, GP by GP, (c, f, mu (B, K), S, Z, w, idx, val, add) for trajectories X (B, K, d).
    The joint predictive covariance is, on the basis route (circle_basis.py; S empty), z_i·z_j +
    add·δ_ij with z = Q φ(θ) given as: the features Z = Φ (B, K, ≥ P) and Q's sparse form idx,
    val (P, r) (w empty); or, diagonal, Z = Φ and w = diag(Q)² (z_i·z_j = Σ_p w_p Φ_ip Φ_jp); or
    Z = Φ Qᵀ and w = 1. On the exact route it is S (B, K, K) + add·I (w and idx empty). The
    arrays are scratch space, valid until the next item."""
    from pipeline.method import kernels   # heavy: numba compiles on first use

    pl = plan(models)
    X = np.ascontiguousarray(X, dtype=float)
    B, K, d = X.shape
    C, F = models.n_classes, models.n_components
    flat = X.reshape(B * K, d)
    use_basis = pl.P_max > 0 and cb.unit_error(flat) <= cb.UNIT_TOL
    if use_basis:
        from scipy.linalg.blas import dtrmm

        Phi = kernels.features(flat / np.linalg.norm(flat, axis=1, keepdims=True), workspace("Phi", (B * K, pl.P_max)))
        means = Phi @ pl.wbar                                          # (B·K, G): every basis mean
        mu = workspace("mu", (B, K))
        Phi3 = Phi.reshape(B, K, pl.P_max)
        for i, (c, f) in enumerate(pl.members):
            g = pl.basis[c][f]
            np.add(means[:, i].reshape(B, K), g.mean, out=mu)
            add = g.noise + models.test_variance[c, f]   # test noise: σ_n² + δ² (gp.py)
            if g.q2 is not None:                          # diagonal form: no whitening at all
                yield c, f, mu, _NONE, Phi3, g.q2, pl.no_idx, pl.no_val, add
                continue
            if g.idx is not None:                         # sparse form: z = Q φ in the kernel
                yield c, f, mu, _NONE, Phi3, _NO_W, g.idx, g.val, add
                continue
            # Z = Φ Qᵀ in place as Zᵀ = Q Φᵀ (Q lower triangular): a TRMM, half a GEMM's flops.
            Z = workspace("Z", (B * K, g.P))                             # C order (B·K, P)
            np.copyto(Z, Phi[:, :g.P])
            out = dtrmm(1.0, pl.q_fortran[i], Z.T, side=0, lower=1, trans_a=0, diag=0, overwrite_b=1)
            if not np.shares_memory(out, Z):  # pragma: no cover - BLAS wrapper made a copy after all
                Z[...] = out.T
            yield c, f, mu, _NONE, Z.reshape(B, K, g.P), pl.ones[:g.P], pl.no_idx, pl.no_val, add
    D2tt = None
    for c in range(C):
        exact_f = [f for f in range(F) if not (use_basis and pl.basis[c][f] is not None)]
        if exact_f:
            if D2tt is None:
                diff = X[:, :, None, :] - X[:, None, :, :]
                D2tt = np.einsum("bkld,bkld->bkl", diff, diff)
            yield from _exact_class(models, pl, c, exact_f, flat, B, K, D2tt)


def _exact_class(models, pl: Plan, c: int, fs, flat, B, K, D2tt):
    """The reference route for class c's components fs, whitening by TRMM with L⁻¹."""
    from scipy.linalg.blas import dtrmm

    fc = models.factors()[c]
    N = len(fc.T)
    D2 = models._sqdist_train(c, flat)
    V = np.empty_like(D2)
    kk = np.empty((B, K, K))
    cov = np.empty((B, K, K))
    for f in fs:
        models._kernel_from_sqdist(c, f, D2, out=V)
        mu = (V @ fc.alpha[f] + models.mean[c, f]).reshape(B, K)
        out = dtrmm(1.0, pl.linv(c, f), V.T, side=0, lower=1, trans_a=0, diag=0, overwrite_b=1)
        if not np.shares_memory(out, V):  # pragma: no cover - BLAS wrapper made a copy after all
            V[...] = out.T
        predictive_covariance(models, c, f, V.reshape(B, K, N), D2tt, kk, cov, instance_term(models, c, f))
        yield c, f, mu, cov, _NONE, _NO_W, pl.no_idx, pl.no_val, 0.0


def not_positive_definite(models: GPClassModels, gps) -> None:
    """Raise the error naming the (class, component) GPs ``gps`` ((c, f) index pairs) whose joint
    predictive covariance is not positive definite."""
    bad = [(models.classes[c], models.components[f]) for c, f in gps]
    raise ValueError(f"joint predictive covariance is not positive definite for (class, component) {bad}: "
                     "white noise too small for the amplitude, or repeated inputs") from None


def named_cholesky(cov: np.ndarray, models: GPClassModels) -> np.ndarray:
    """The Cholesky factor of ``cov`` (..., C, F, n, n), or the error naming every (class, component)
    whose covariance is not positive definite."""
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
        not_positive_definite(models, zip(*np.nonzero(~ok)))
