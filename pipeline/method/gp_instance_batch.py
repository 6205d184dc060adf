"""Every instance-term fit of a bank at once (docs/design.md §5, "Instances differ" and "Fitting
every GP at once").

The objective is ``pipeline.method.gp_instance_fit.JointObjective``'s, per (class, component): the
log marginal likelihood of ``K = a·E_ℓ + B ∘ b·E_λ + σ² I`` over t = log(a, ℓ, σ², b, λ), plus the
inverse-gamma log priors on ℓ and σ² (``gp_batch.add_log_prior``), inside the log bounds; the same
starts and scipy's L-BFGS-B with its defaults. The runs are driven in lock step and polished by
``gp_batch.fit_stack`` (the plain fit's machinery); what is new is the stacked objective.

Two exact evaluations of it, from the class's inputs and instance labels (shared by its components):

* **balanced** (every instance has the same multiset of inputs, as a category's turntable
  instances at the same azimuths): with the m instances' p views each in one order,
  K = J_m ⊗ A + I_m ⊗ Q (A = a·E_ℓ, Q = b·E_λ + σ² I, p x p). An orthogonal change of basis
  across instances whose first vector is the mean splits K into P = m·A + Q for the instance mean
  and Q for each of the m - 1 contrasts, so y'K⁻¹y = ȳ'P⁻¹ȳ·m + tr(Q⁻¹R) (R: the scatter of the
  instances' target vectors about their mean) and log det K = log det P + (m - 1) log det Q:
  two p x p factorisations where the per-fit route factorises n x n (n = m·p).
* **dense**, otherwise: K itself, (n, n), stacked.

A factorisation that fails scores -1e300 with a zero gradient, the per-fit objective's 1e300.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.method.bank_index import content_digest
from pipeline.method.gp_prior import LogInverseGamma, LogitBeta
from pipeline.method.gp_batch import BLOCK, LOG_2PI, Result, add_log_prior, cholesky_inverses, fit_stack, \
    setulb_available

FAILED = -1e300


@dataclass
class InstanceProblem:
    """One (class, component) instance-term fit: centred inputs (n, d), centred targets (n,),
    integer instance labels (n,), log bounds (5, 2), prior rows (2, 2) (alpha, beta) of log ℓ and
    log σ² (NaN: none), starts (S, 5), and the instance term's prior rows (2, 2)
    (``instance_prior_rows``: the Beta law of b / (a + b), the inverse-gamma law of λ; NaN: none)."""
    X: np.ndarray
    y: np.ndarray
    labels: np.ndarray
    log_bounds: np.ndarray
    prior: np.ndarray
    starts: np.ndarray
    instance_prior: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    structure: str = field(default="", repr=False)

    def __post_init__(self):
        self.structure = content_digest(np.asarray(self.X, float), np.asarray(self.labels, np.int64))


def balanced_order(X: np.ndarray, labels: np.ndarray) -> np.ndarray | None:
    """A view order (m, p) in which every instance's p views are the same inputs in the same
    order, or None when the instances' input multisets differ."""
    X = np.asarray(X, float)
    inst = np.unique(labels)
    rows = []
    for i in inst:
        idx = np.flatnonzero(labels == i)
        rows.append(idx[np.lexsort(X[idx].T[::-1])])
    if len({len(r) for r in rows}) != 1:
        return None
    ref = X[rows[0]]
    if any(not np.array_equal(X[r], ref) for r in rows[1:]):
        return None
    return np.stack(rows)


class _Structure:
    """What a class's components share: squared distances and either the balanced order or B."""

    def __init__(self, X: np.ndarray, labels: np.ndarray):
        self.order = balanced_order(X, labels)
        pts = X if self.order is None else X[self.order[0]]
        self.D2 = np.sum((pts[:, None, :] - pts[None, :, :]) ** 2, axis=-1)
        self.m = 1 if self.order is None else len(self.order)
        self.B = None if self.order is not None else (labels[:, None] == labels[None, :]).astype(float)
        self.n = len(X)

    def reduce(self, y: np.ndarray):
        """Balanced: (sqrt(m)·ȳ (p,), R (p, p)); dense: (y, None)."""
        if self.order is None:
            return y, None
        Yi = y[self.order]                      # (m, p)
        ybar = Yi.mean(axis=0)
        R = Yi.T @ Yi - self.m * np.outer(ybar, ybar)
        return np.sqrt(self.m) * ybar, R


def stacked_inverses(K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``gp_batch.cholesky_inverses``'s (K⁻¹, half log det K, positive definite) for a stack of
    small matrices, through numpy's stacked Cholesky and triangular inverse (one call each, where
    the per-matrix LAPACK loop costs more in Python than in arithmetic at p = 16); a stack with a
    matrix that is not positive definite goes through the per-matrix loop, which flags it."""
    try:
        L = np.linalg.cholesky(K)
    except np.linalg.LinAlgError:
        return cholesky_inverses(K)
    Linv = np.linalg.inv(L)
    return (np.swapaxes(Linv, 1, 2) @ Linv, np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1),
            np.ones(len(K), bool))


def objective(st: _Structure, z: np.ndarray, R: np.ndarray | None, theta: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """LML (B,) and its gradient in t (B, 5) for B stacked fits of one structure: ``z`` (B, p)
    the reduced targets (``_Structure.reduce``), ``R`` (B, p, p) or None (dense)."""
    Bn, p = z.shape
    a, ell, s, b, lam = (np.exp(theta[:, i])[:, None, None] for i in range(5))
    A = a * np.exp(-st.D2 / (2 * ell * ell))
    H = b * np.exp(-st.D2 / (2 * lam * lam))
    if st.B is not None:
        H = H * st.B
    diag = np.arange(p)
    Q = H.copy()
    Q[:, diag, diag] += s[:, 0]
    P = st.m * A + Q if R is not None else A + Q
    lml, grad = np.full(Bn, FAILED), np.zeros((Bn, 5))
    Pinv, hP, ok = stacked_inverses(P)
    if R is not None:
        Qinv, hQ, okq = stacked_inverses(Q)
        ok &= okq
    if not ok.any():
        return lml, grad
    alpha = (Pinv[ok] @ z[ok][:, :, None])[:, :, 0]
    quad = np.einsum("bi,bi->b", z[ok], alpha)
    logdet = 2 * hP[ok]
    W1 = alpha[:, :, None] * alpha[:, None, :] - Pinv[ok]
    W2 = 0.0
    if R is not None:
        QR = Qinv[ok] @ R[ok]
        quad = quad + np.trace(QR, axis1=1, axis2=2)
        logdet = logdet + (st.m - 1) * 2 * hQ[ok]
        W2 = QR @ Qinv[ok] - (st.m - 1) * Qinv[ok]
    lml[ok] = -0.5 * quad - 0.5 * logdet - 0.5 * st.n * LOG_2PI
    # dP = m·dA for a and ℓ (dQ = 0); σ², b and λ act on P and Q alike (dQ): W1 and W2 summed.
    Wq = W1 + W2
    mA = st.m * A[ok]
    g = np.empty((int(ok.sum()), 5))
    g[:, 0] = 0.5 * np.einsum("bij,bij->b", W1, mA)
    g[:, 1] = 0.5 * np.einsum("bij,bij->b", W1, mA * st.D2) / ell[ok, 0, 0] ** 2
    g[:, 2] = 0.5 * s[ok, 0, 0] * np.trace(Wq, axis1=1, axis2=2)
    Hk = H[ok]
    g[:, 3] = 0.5 * np.einsum("bij,bij->b", Wq, Hk)
    g[:, 4] = 0.5 * np.einsum("bij,bij->b", Wq, Hk * st.D2) / lam[ok, 0, 0] ** 2
    grad[ok] = g
    return lml, grad


class InstanceStack:
    """The problems' data for ``gp_batch.fit_stack``: one structure per class, reduced targets per
    problem; ``evaluate`` stacks the runs of one structure ``BLOCK`` at a time."""

    def __init__(self, problems: list[InstanceProblem]):
        self.problems = problems
        seen: dict[bytes, int] = {}
        self.structures: list[_Structure] = []
        self.sid = np.empty(len(problems), int)
        self.z, self.R = [], []
        for i, pb in enumerate(problems):
            if pb.structure not in seen:
                seen[pb.structure] = len(self.structures)
                self.structures.append(_Structure(np.asarray(pb.X, float), np.asarray(pb.labels)))
            self.sid[i] = seen[pb.structure]
            z, R = self.structures[self.sid[i]].reduce(np.asarray(pb.y, float))
            self.z.append(z)
            self.R.append(R)
        self.prior = np.stack([pb.prior for pb in problems]) if problems else np.empty((0, 2, 2))
        self.iprior = np.stack([pb.instance_prior for pb in problems]) if problems else np.empty((0, 2, 2))

    def evaluate(self, which: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lml, grad = np.empty(len(which)), np.empty((len(which), 5))
        sids = self.sid[which]
        for sid in np.unique(sids):
            rows = np.nonzero(sids == sid)[0]
            st = self.structures[sid]
            for s0 in range(0, len(rows), BLOCK):
                r = rows[s0:s0 + BLOCK]
                idx = which[r]
                z = np.stack([self.z[i] for i in idx])
                R = None if st.order is None else np.stack([self.R[i] for i in idx])
                with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
                    lml[r], grad[r] = objective(st, z, R, theta[r])
        lp = add_log_prior(self.prior[which], theta, grad) + add_instance_prior(self.iprior[which], theta, grad)
        failed = lml <= FAILED           # the per-fit objective's 1e300 and zero gradient there
        lp[failed], grad[failed] = 0.0, 0.0
        return lml, lp, grad

    def laplace_sd(self, theta: np.ndarray, step: float = 1e-4) -> list[np.ndarray | None]:
        """Per problem, JointObjective.laplace_sd's standard deviations of t at ``theta`` (P, 5):
        the inverse Hessian of -(LML + log prior) from central differences of the gradient."""
        P, which = len(theta), np.arange(len(theta))
        H = np.empty((P, 5, 5))
        for j in range(5):
            e = np.zeros(5)
            e[j] = step
            gp_, gm = (_objective_gradient(self.evaluate(which, theta + sgn * e)) for sgn in (1, -1))
            H[:, j] = (gp_ - gm) / (2 * step)
        return [laplace_from_hessian(h) for h in H]


def instance_prior_rows(split, lam_law) -> np.ndarray:
    """(2, 2) rows (alpha, beta): the split's ``gp_prior.LogitBeta`` and λ's
    ``gp_prior.LogInverseGamma`` (NaN where none)."""
    out = np.full((2, 2), np.nan)
    for j, law in enumerate((split, lam_law)):
        if law is not None:
            out[j] = (law.alpha, law.beta)
    return out


def add_instance_prior(prior: np.ndarray, theta: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """The instance term's log priors (B,), their slopes added to ``grad`` (B, 5) in place: row 0
    of ``prior`` (B, 2, 2) the Beta(alpha, beta) law of r = b / (a + b) as a law of u = log b -
    log a (``gp_prior.LogitBeta``), row 1 the inverse-gamma law of log λ; NaN where none."""
    lp = np.zeros(len(theta))
    has = np.isfinite(prior[:, 0, 0])
    if has.any():   # the laws' own arithmetic, on arrays of shapes
        du_lp, du = LogitBeta(prior[has, 0, 0], prior[has, 0, 1])(theta[has, 3] - theta[has, 0])
        lp[has] += du_lp
        grad[has, 3] += du
        grad[has, 0] -= du
    has = np.isfinite(prior[:, 1, 0])
    if has.any():
        t_lp, dt = LogInverseGamma(prior[has, 1, 0], prior[has, 1, 1], np.nan, np.nan)(theta[has, 4])
        lp[has] += t_lp
        grad[has, 4] += dt
    return lp


def _objective_gradient(ev) -> np.ndarray:
    lml, _, grad = ev
    return np.where((lml > FAILED)[:, None], -grad, 0.0)


def laplace_from_hessian(H: np.ndarray) -> np.ndarray | None:
    """sqrt(diag(H⁻¹)) of the symmetrised Hessian, or None where it is not positive definite."""
    H = 0.5 * (H + H.T)
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return None
    return np.sqrt(np.diag(np.linalg.inv(H)))


def fit_instance_problems(problems: list[InstanceProblem], *, polish: bool = True, lockstep: bool | None = None
                          ) -> tuple[list[Result], InstanceStack]:
    """Every problem's MAP fit (all starts in one lock-step set of runs, the best polished), and
    the stack (for the Laplace intervals)."""
    from threadpoolctl import threadpool_limits

    stack = InstanceStack(problems)
    if not problems:
        return [], stack
    lockstep = setulb_available() if lockstep is None else lockstep
    with threadpool_limits(1, user_api="blas"):
        return fit_stack(stack, polish, lockstep), stack
