"""The GP predictive on the unit circle as Bayesian linear regression on Fourier features.

For unit inputs ``x = (cos θ, sin θ)`` the kernel ``a·exp(-‖x - x'‖²/(2ℓ²))`` depends on the angle
difference only, and ``exp(κ cos Δ) = Σ_n I_n(κ) e^{inΔ}`` (κ = 1/ℓ², I_n the modified Bessel
function) gives

    k(θ, θ') = Σ_{|n| ≤ M} a·ive(n, κ)·e^{in(θ-θ')} + r_M,   |r_M| ≤ a·τ_M,  τ_M = 2 Σ_{n>M} ive(n, κ)

with ``ive(n, κ) = I_n(κ) e^{-κ}``. The truncated kernel is ``φ(θ)ᵀ D φ(θ')`` for the P = 2M + 1
features ``φ = (1, cos θ, sin θ, …, cos Mθ, sin Mθ)`` and the diagonal prior ``D``; the GP is then
exactly Bayesian linear regression on φ (weights ~ N(0, D), noise σ_n²), whose predictive is

    μ(θ) = m + φ(θ)ᵀ w̄,     cov(θ_i, θ_j) = z(θ_i)·z(θ_j) + σ_n² δ_ij,   z(θ) = Q φ(θ),

with ``Q = R⁻¹ D^{1/2}``, ``R Rᵀ = I + XᵀX``, ``X = Ψ D^{1/2} / σ_n`` (Ψ: features of the training
angles) and ``w̄ = D^{1/2} (I + XᵀX)⁻¹ Xᵀ (y - m) / σ_n``. A trajectory then costs P² per point
(one GEMM over every row of a block) instead of the N² triangular solve against N training views,
and no exp at all; the covariance is a sum of squares, so it never loses digits to the
``k** - k*ᵀK⁻¹k*`` cancellation.

Exactness: M is the smallest order with ``τ_M ≤ KERNEL_TOL`` = 1e-17, below the unit roundoff
(1.1e-16) of forming any kernel entry in the reference route: the basis route computes the GP of a
kernel perturbed, entry by entry, less than rounding perturbs the reference's own. Inputs must be
unit vectors to ``UNIT_TOL`` (what ``project_unit_circle`` writes); a (class, component) whose P
would cost more than the reference route's triangular solve, or whose class's training inputs are
not unit vectors, stays on the exact route (``pipeline/method/engine.py``).

Sparse form. Training angles evenly spaced on the circle (a turntable: BigBIRD's 120 views at
3°) make the N training rows of the features orthogonal except between orders that alias
(n ≡ ±n' mod N), so ``I + XᵀX`` is block diagonal with blocks of a few aliased orders, and so is
Q in exact arithmetic: diagonal when P ≤ N, about 4 entries per row when N < P < 2N. Then
z(θ) = Q φ(θ) costs r·P per point for r entries per row instead of P² (the diagonal: the
covariance Σ_p q_p² φ_p(θ) φ_p(θ') costs P per pair). Computed Q has rounding noise E where the
exact one has zeros (|E| ~ 1e-16 of max|Q|). The sparse form drops every entry below
``DROP_REL``·max|Q| (the largest of its thresholds that passes) if that changes no covariance entry by more than ``SPARSE_TOL``·a:
|Δ cov| ≤ 2√a‖E‖₂√(M+1) + ‖E‖₂²(M+1), from ‖z‖² ≤ a and ‖φ‖² = M + 1 (‖E‖₂ bounded by the
Frobenius norm, or computed where that is not enough). 1e-14·a is the size of the reference
route's own rounding error in a covariance entry: against 40-digit arithmetic (mpmath) the
reference's entries of three default-run GPs were off by 5e-16·a to 1.2e-14·a, the basis
route's by 1e-17·a to 3e-17·a. tests/test_engine.py holds the result equal to the reference to
1e-9 on the log posteriors at noise variances down to 1e-5. Scattered or incomplete rings keep
the full triangular Q.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KERNEL_TOL = 1e-17      # bound on |k - k_M| / a for every pair of unit inputs
SPARSE_TOL = 1e-14      # bound on the covariance change / a that the sparse form may make
DROP_REL = (1e-13, 1e-14, 1e-15)   # entries of Q below one of these times max|Q| are dropped if the bound allows
MAX_ROW = 8             # the sparse form is kept up to this many entries per row of Q
UNIT_TOL = 1e-15        # | ‖x‖ - 1 | allowed for the basis route (project_unit_circle writes ~2e-16)
MAX_ORDER = 400


def tail_order(kappa: float, tol: float = KERNEL_TOL) -> tuple[int, float]:
    """Smallest M with τ_M = 2 Σ_{n>M} ive(n, κ) ≤ tol, and that τ_M; (MAX_ORDER + 1, inf) if none."""
    from scipy.special import ive

    n = np.arange(MAX_ORDER + 60)
    v = ive(n, kappa)
    tails = 2.0 * np.cumsum(v[::-1])[::-1]            # tails[m] = 2 Σ_{n ≥ m}
    ok = np.nonzero(tails[1:MAX_ORDER + 2] <= tol)[0]  # tails[M + 1] is τ_M
    if not len(ok):
        return MAX_ORDER + 1, math.inf
    M = int(ok[0])
    return M, float(tails[M + 1])


def features(x: np.ndarray, P: int) -> np.ndarray:
    """φ (n, P) of unit vectors x (n, 2): 1, cos θ, sin θ, cos 2θ, sin 2θ, … by the angle-addition
    recurrence (relative error grows like n·ε, as cos(nθ) from a rounded θ would)."""
    return fill_features(np.empty((len(x), P)), x)


def fill_features(out, x):
    """``features`` into a preallocated (n, P) array ``out``: numpy or torch alike (only slicing
    and elementwise arithmetic), so both engines compute the same recurrence."""
    P = out.shape[1]
    out[:, 0] = 1.0
    if P == 1:
        return out
    c1, s1 = x[:, 0], x[:, 1]
    out[:, 1], out[:, 2] = c1, s1
    for k in range(2, (P - 1) // 2 + 1):
        c, s = out[:, 2 * k - 3], out[:, 2 * k - 2]
        out[:, 2 * k - 1] = c * c1 - s * s1
        out[:, 2 * k] = s * c1 + c * s1
    return out


def prior_weights(a: float, kappa: float, M: int) -> np.ndarray:
    """Diagonal of D (P,): a·ive(0, κ), then 2a·ive(n, κ) twice (cos, sin) for n = 1..M."""
    from scipy.special import ive

    v = ive(np.arange(M + 1), kappa)
    return a * np.concatenate([[v[0]], np.repeat(2.0 * v[1:], 2)])


def unit_error(x: np.ndarray) -> float:
    """max | ‖x‖ - 1 | over rows (inf for an empty or non-2D set)."""
    if x.ndim != 2 or x.shape[1] != 2 or not len(x):
        return math.inf
    return float(np.max(np.abs(np.sqrt(np.einsum("ij,ij->i", x, x)) - 1.0)))


@dataclass
class BasisGP:
    """One (class, component) on the basis route: z = Q φ[:P], μ = m + φ[:P]·w̄."""
    P: int
    QT: np.ndarray | None   # (P, P) Qᵀ, upper triangular: Z = Φ Qᵀ (None when P > N: sparse form only)
    QF: np.ndarray | None   # (P, P) Q, lower triangular, Fortran order (the TRMM operand)
    wbar: np.ndarray        # (P,)
    mean: float
    noise: float
    tau: float              # kernel truncation bound τ_M (relative to a)
    idx: np.ndarray | None = None  # (P, r) column indices of Q's kept entries (sparse form), padded
    val: np.ndarray | None = None  # (P, r) their values (0 in the padding)
    q2: np.ndarray | None = None   # (P,) diag(Q)² when the sparse form is diagonal (r = 1)
    sparse_bound: float = math.inf # the sparse form's bound on |Δ cov| / a


def build(x_train: np.ndarray, y: np.ndarray, mean: float, a: float, ell: float, noise: float) -> BasisGP | None:
    """The basis-route factors of one GP, or None when its order would exceed MAX_ORDER, or when
    P exceeds the N training views and Q has no sparse form (the exact route is cheaper then)."""
    from scipy.linalg import cho_solve, solve_triangular

    kappa = 1.0 / (ell * ell)
    M, tau = tail_order(kappa)
    if M > MAX_ORDER:
        return None
    P = 2 * M + 1
    xt = x_train / np.linalg.norm(x_train, axis=1, keepdims=True)
    d_half = np.sqrt(prior_weights(a, kappa, M))
    sig = math.sqrt(noise)
    Xm = features(xt, P) * (d_half / sig)              # (N, P)
    A = Xm.T @ Xm
    A[np.diag_indices(P)] += 1.0
    R = np.linalg.cholesky(A)                          # eigenvalues >= 1: well conditioned
    Q = solve_triangular(R, np.diag(d_half), lower=True)
    wbar = d_half * cho_solve((R, True), Xm.T @ (np.asarray(y, float) - mean) / sig)
    sp = sparse_form(Q, a, M)
    if P > len(xt):
        if sp[0] is None:
            return None
        return BasisGP(P, None, None, wbar, float(mean), float(noise), tau, *sp)
    return BasisGP(P, np.ascontiguousarray(Q.T), np.asfortranarray(Q), wbar, float(mean), float(noise), tau, *sp)


def dense_q(g: BasisGP) -> np.ndarray:
    """Q (P, P) of a basis GP, from its sparse form when the dense one is not kept."""
    if g.QF is not None:
        return np.ascontiguousarray(g.QF)
    Q = np.zeros((g.P, g.P))
    np.add.at(Q, (np.repeat(np.arange(g.P), g.idx.shape[1]), g.idx.ravel()), g.val.ravel())
    return Q


def sparse_form(Q: np.ndarray, a: float, M: int):
    """(idx, val, q2, bound) of Q's sparse form (module docstring), or (None, None, None, bound)
    when the dropped entries' bound exceeds SPARSE_TOL or a row keeps more than MAX_ROW entries."""
    mag = np.abs(Q)

    def bound_for(e: float) -> float:   # ‖E φ‖ ≤ ‖E‖₂ ‖φ‖, ‖E‖₂ ≤ ‖E‖_F
        return (2.0 * math.sqrt(a) * e * math.sqrt(M + 1) + e * e * (M + 1)) / a

    bound = math.inf
    for rel in DROP_REL:                  # the sparsest threshold whose bound holds
        keep = mag > rel * mag.max()
        r = int(keep.sum(axis=1).max())
        if r > MAX_ROW:
            break
        bound = bound_for(float(np.linalg.norm(Q[~keep])))
        if bound > SPARSE_TOL:            # the spectral norm itself (an SVD), only where it matters
            bound = bound_for(float(np.linalg.norm(np.where(keep, 0.0, Q), 2)))
        if bound <= SPARSE_TOL:
            break
    if bound > SPARSE_TOL:
        return None, None, None, bound
    P = len(Q)
    idx = np.zeros((P, r), dtype=np.int64)
    val = np.zeros((P, r))
    for p in range(P):
        cols = np.nonzero(keep[p])[0]
        idx[p, :len(cols)] = cols
        val[p, :len(cols)] = Q[p, cols]
    q2 = np.ascontiguousarray(val[:, 0] ** 2) if r == 1 and np.array_equal(idx[:, 0], np.arange(P)) else None
    return idx, val, q2, bound
