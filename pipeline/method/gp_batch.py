"""Every GP fit of a bank at once (docs/design.md §5, "Fitting every GP at once").

The objective is scikit-learn's, per fit: the log marginal likelihood of
``ConstantKernel * RBF + WhiteKernel`` on the centred targets plus the log hyperpriors of
``pipeline/method/gp_prior.py``, over theta = (log a, log l, log noise) (``kernel.theta`` order)
inside the log bounds. The optimizer is scipy's L-BFGS-B with its defaults, one run per start
(the initial point and ``restarts`` draws log-uniform in the bounds from ``RandomState(rs)``,
the draws scikit-learn makes), exactly as ``GaussianProcessRegressor.fit`` runs it. What changes
is who evaluates: every run is driven through scipy's reverse-communication routine (``setulb``)
in lock step, and each round the objective and its analytic gradient are computed for all runs
waiting for one with stacked arrays: one Cholesky and inverse per fit of the (u, u) matrix of its
u distinct training inputs (``objective``: a category class's instances share 16 azimuths). Each run keeps
its own L-BFGS-B state, so its convergence tests act per fit, not on a sum. Where this scipy has
no ``setulb`` of the known signature, the runs go one by one through ``scipy.optimize.minimize``
(same numbers, slower).

The best start is chosen on the objective re-evaluated at each run's final point, then polished by
one more L-BFGS-B run from it with tight tolerances (``POLISH``): L-BFGS-B only descends, so the
optimum is scikit-learn's or, where scikit-learn stopped early on a flat ridge, slightly higher.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipeline.method.bank_index import content_digest
from pipeline.method.gp_workers import shared

LOG_2PI = float(np.log(2 * np.pi))
BLOCK = 128          # runs per stacked evaluation: (BLOCK, n, n) arrays stay a few tens of MB
# scipy's L-BFGS-B defaults (what scikit-learn's fits run with).
DEFAULTS = dict(maxcor=10, ftol=2.2204460492503131e-09, gtol=1e-5, maxfun=15000, maxiter=15000, maxls=20)
# The polish: converge on the projected gradient, not on a relative change of f that a flat ridge
# satisfies early; bounded, since it only refines.
POLISH = dict(DEFAULTS, ftol=1e-15, gtol=1e-9, maxiter=200, maxfun=400)
SETULB_SIGNATURE = "setulb(m,x,l,u,nbd,f,g,factr,pgtol,wa,iwa,task,lsave,isave,dsave,maxls,ln_task)"


@dataclass
class Problem:
    """One (class, component) fit: inputs (n, d), centred targets (n,), log bounds (3, 2), the
    hyperpriors' (alpha, beta) for log l and log noise (NaN rows: none), the starts (S, 3)."""
    X: np.ndarray
    y: np.ndarray
    log_bounds: np.ndarray
    prior: np.ndarray
    starts: np.ndarray
    key: str = field(default="")

    def __post_init__(self):
        self.key = content_digest(*(np.asarray(a, float) for a in
                                    (self.X, self.y, self.log_bounds, self.prior, self.starts)))[:16]


@dataclass
class Result:
    """A fit's chosen theta, its objective (LML + log prior) there, the LML alone, the log prior,
    and what each start's L-BFGS-B run ended with (status, message, iterations)."""
    theta: np.ndarray
    objective: float
    lml: float
    log_prior: float
    runs: list[dict]
    start: int = -1     # the start whose run was chosen (then polished)


def sq_dists(X: np.ndarray) -> np.ndarray:
    """Squared distances (n, n) between the rows of X, as scikit-learn's RBF forms them (pdist)."""
    from scipy.spatial.distance import pdist, squareform

    return squareform(pdist(np.asarray(X, float), metric="sqeuclidean"))


def objective(D: np.ndarray, w: np.ndarray, z: np.ndarray, ssw: np.ndarray, n: np.ndarray, theta: np.ndarray,
              prior: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For B stacked fits: LML (B,), log prior (B,) and the gradient of their sum w.r.t. theta (B, 3).

    Each fit's n training inputs are reduced to their u distinct points (``reduce_inputs``): ``D``
    (B, u, u) squared distances between them, ``w`` (B, u) how many inputs share each, ``z`` (B, u)
    the centred targets summed per point over sqrt(w), ``ssw`` (B,) the targets' squared deviations
    from their point's mean, ``n`` (B,). With U the (n, u) indicator and W = U^T U,
    K = noise I + U A U^T (A = a exp(-D / 2l^2)); with M = noise I + W^1/2 A W^1/2 and q = M^-1 z:
    y^T K^-1 y = ssw / noise + z^T q, log det K = (n - u) log noise + log det M, U^T K^-1 y = W^1/2 q,
    U^T K^-1 U = W^1/2 M^-1 W^1/2, tr K^-1 = (n - u) / noise + tr M^-1: the LML and its gradient
    exactly, from u x u matrices (u = n when the inputs are distinct; a category class's instances
    share the 16 azimuths, u = 16). ``prior`` (B, 2, 2): rows (alpha, beta) of the inverse-gamma
    laws of l and noise (NaN: none). An M that is not positive definite gives LML -inf and a zero
    gradient, as scikit-learn does for K."""
    B, u = z.shape
    a, ell, s = (np.exp(theta[:, i])[:, None, None] for i in range(3))
    Dl = D / ell ** 2
    A = a * np.exp(-0.5 * Dl)
    sw = np.sqrt(w)
    distinct = bool(np.all(w == 1))   # the common case: no weighting to apply
    sw2 = None if distinct else sw[:, :, None] * sw[:, None, :]
    M = A.copy() if distinct else A * sw2
    M[:, np.arange(u), np.arange(u)] += s[:, 0]
    lml = np.full(B, -np.inf)
    grad = np.zeros((B, 3))
    Minv, half_logdet, ok = cholesky_inverses(M)
    if ok.any():
        k = slice(None) if ok.all() else ok   # views, not copies, when every M factorised
        Minv, A, Dl, zz, s1 = Minv[k], A[k], Dl[k], z[k], s[k, 0, 0]
        ssw_, n_, sw_ = ssw[k], n[k], sw[k]
        q = (Minv @ zz[:, :, None])[:, :, 0]
        quad = ssw_ / s1 + np.einsum("bi,bi->b", zz, q)
        logdet = (n_ - u) * np.log(s1) + 2 * half_logdet[k]
        lml[k] = -0.5 * quad - 0.5 * logdet - 0.5 * n_ * LOG_2PI
        # dLML/dtheta_j = 0.5 (alpha^T dK_j alpha - tr(K^-1 dK_j)), alpha = K^-1 y; dK/dlog a = U A U^T,
        # dK/dlog l = U (A * D / l^2) U^T, dK/dlog noise = noise I.
        v = sw_ * q
        P = Minv if distinct else Minv * sw2[k]
        g_ok = np.empty((len(zz), 3))
        for j, Aj in ((0, A), (1, A * Dl)):
            g_ok[:, j] = 0.5 * (np.einsum("bi,bi->b", v, (Aj @ v[:, :, None])[:, :, 0])
                                - np.einsum("bij,bij->b", P, Aj))
        g_ok[:, 2] = 0.5 * (ssw_ / s1 + s1 * np.einsum("bi,bi->b", q, q) - (n_ - u)
                            - s1 * np.trace(Minv, axis1=1, axis2=2))
        grad[k] = g_ok
    return lml, add_log_prior(prior, theta, grad), grad


def add_log_prior(prior: np.ndarray, theta: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """The log hyperpriors (B,) of stacked fits, their slopes added to ``grad`` (B, p) in place:
    ``prior`` (B, 2, 2) rows (alpha, beta) of the inverse-gamma laws of theta[:, 1] (the length
    scale) and theta[:, 2] (the noise), NaN where none."""
    lp = np.zeros(len(theta))
    for j, i in ((0, 1), (1, 2)):   # prior row j acts on theta[i]
        has = np.isfinite(prior[:, j, 0])
        if has.any():
            al, be, t = prior[has, j, 0], prior[has, j, 1], theta[has, i]
            e = be * np.exp(-t)
            lp[has] += -al * t - e
            grad[has, i] += -al + e
    return lp


def cholesky_inverses(K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K^-1 (B, n, n), half log det K (B,) and which K are positive definite, from one LAPACK
    Cholesky (potrf) and inverse-from-Cholesky (potri) per matrix: half the work of a general
    inverse, and a failed factorisation flags its matrix instead of raising for the stack."""
    from scipy.linalg import lapack

    B, n, _ = K.shape
    inv, half_logdet, ok = np.empty_like(K), np.zeros(B), np.ones(B, bool)
    upper = np.triu(np.ones((n, n), bool), 1)
    for b in range(B):
        c, info = lapack.dpotrf(K[b], lower=1, clean=0)
        if info != 0:
            ok[b] = False
            continue
        half_logdet[b] = np.log(np.diagonal(c)).sum()
        ci, info = lapack.dpotri(c, lower=1)
        if info != 0:
            ok[b] = False
            continue
        np.copyto(ci, ci.T, where=upper)   # potri fills the lower triangle: mirror it (a third of fancy indexing's time)
        inv[b] = ci
    return inv, half_logdet, ok


def setulb_available() -> bool:
    """Whether this scipy's L-BFGS-B routine has the reverse-communication signature driven here."""
    try:
        from scipy.optimize import _lbfgsb
    except ImportError:
        return False
    return (getattr(_lbfgsb.setulb, "__doc__", "") or "").strip().startswith(SETULB_SIGNATURE)


def _messages(task: np.ndarray) -> str:
    from scipy.optimize._lbfgsb_py import status_messages, task_messages

    return status_messages[int(task[0])] + ": " + task_messages[int(task[1])]


def lbfgsb_lockstep(fg: Callable, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, options: dict) -> list[dict]:
    """L-BFGS-B runs from each row of ``x0`` (T, p) within [lo, hi], advanced together: each round
    every run that wants f and g at its x gets them from one call ``fg(idx, X) -> (f (k,), g (k, p))``.
    The per-run loop is scipy's ``_minimize_lbfgsb``'s (same state, tests and limits). Returns per
    run {x, fun, status, message, nit, nfev}."""
    from scipy.optimize import _lbfgsb

    T, p = x0.shape
    m, eps = options["maxcor"], np.finfo(float).eps
    factr = options["ftol"] / eps
    runs = []
    for t in range(T):
        runs.append(dict(
            x=np.clip(np.array(x0[t], float), lo[t], hi[t]), f=np.array(0.0), g=np.zeros(p),
            wa=np.zeros(2 * m * p + 5 * p + 11 * m * m + 8 * m), iwa=np.zeros(3 * p, np.int32),
            task=np.zeros(2, np.int32), ln_task=np.zeros(2, np.int32), lsave=np.zeros(4, np.int32),
            isave=np.zeros(44, np.int32), dsave=np.zeros(29), nit=0, nfev=0, last=None, done=False))
    nbd = np.full(p, 2, np.int32)
    active = list(range(T))
    while active:
        want = []
        for t in active:
            r = runs[t]
            while True:
                _lbfgsb.setulb(m, r["x"], lo[t], hi[t], nbd, r["f"], r["g"], factr, options["gtol"], r["wa"],
                               r["iwa"], r["task"], r["lsave"], r["isave"], r["dsave"], options["maxls"],
                               r["ln_task"])
                if r["task"][0] == 3:        # wants f and g at x
                    if r["last"] is not None and np.array_equal(r["x"], r["last"]):
                        continue               # scipy's cache: the same x is not evaluated again
                    want.append(t)
                    break
                if r["task"][0] == 1:        # a new iterate
                    r["nit"] += 1
                    if r["nit"] >= options["maxiter"]:
                        r["task"][:] = (5, 504)
                    elif r["nfev"] > options["maxfun"]:
                        r["task"][:] = (5, 502)
                    continue
                r["done"] = True
                break
        if want:
            X = np.stack([runs[t]["x"] for t in want])
            f, g = fg(np.asarray(want), X)
            for k, t in enumerate(want):
                r = runs[t]
                r["f"], r["g"], r["last"] = np.float64(f[k]), np.array(g[k], float), r["x"].copy()
                r["nfev"] += 1
        active = [t for t in active if not runs[t]["done"]]
    out = []
    for r in runs:
        status = 0 if r["task"][0] == 4 else (1 if (r["nfev"] > options["maxfun"] or r["nit"] >= options["maxiter"])
                                               else 2)
        out.append({"x": r["x"].copy(), "fun": float(r["f"]), "status": status, "message": _messages(r["task"]),
                    "nit": r["nit"], "nfev": r["nfev"]})
    return out


def lbfgsb_sequential(fg: Callable, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, options: dict) -> list[dict]:
    """The same runs one at a time through ``scipy.optimize.minimize`` (public interface)."""
    from scipy import optimize

    out = []
    for t in range(len(x0)):
        def one(x, t=t):
            f, g = fg(np.array([t]), x[None])
            return float(f[0]), np.array(g[0], float)
        res = optimize.minimize(one, x0[t], method="L-BFGS-B", jac=True, bounds=list(zip(lo[t], hi[t])),
                                options={k: options[k] for k in ("maxcor", "ftol", "gtol", "maxfun", "maxiter", "maxls")})
        out.append({"x": np.array(res.x), "fun": float(res.fun), "status": int(res.status), "message": str(res.message),
                    "nit": int(res.nit), "nfev": int(res.nfev)})
    return out


def reduce_inputs(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A training set's distinct inputs: their squared distances (u, u), multiplicities (u,) and
    each input's point (n,)."""
    pts, inv, w = np.unique(np.asarray(X, float), axis=0, return_inverse=True, return_counts=True)
    return sq_dists(pts), w.astype(float), inv.reshape(-1)


def reduce_targets(y: np.ndarray, inv: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """(z, ssw) of ``objective`` for centred targets y (n,) on the points ``inv``."""
    sums = np.bincount(inv, weights=y, minlength=len(w))
    return sums / np.sqrt(w), float(((y - (sums / w)[inv]) ** 2).sum())


class Stack:
    """The runs' data: each problem's reduced targets, the distinct input sets' reductions."""

    def __init__(self, problems: list[Problem]):
        self.problems = problems
        keys: dict[bytes, int] = {}
        self.xset = np.empty(len(problems), int)
        self.sets: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.z, self.ssw = [], np.empty(len(problems))
        for i, p in enumerate(problems):
            k = np.ascontiguousarray(p.X, float).tobytes() + str(p.X.shape).encode()
            if k not in keys:
                keys[k] = len(self.sets)
                self.sets.append(reduce_inputs(p.X))
            self.xset[i] = keys[k]
            D, w, inv = self.sets[keys[k]]
            z, self.ssw[i] = reduce_targets(p.y, inv, w)
            self.z.append(z)
        self.u = np.array([len(self.sets[x][1]) for x in self.xset])
        self.n = np.array([len(p.y) for p in problems], float)

    def evaluate(self, which: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(LML, log prior, gradient of their sum) of problems ``which`` at ``theta``: grouped by
        the number of distinct inputs and stacked ``BLOCK`` at a time."""
        lml, lp, grad = np.empty(len(which)), np.empty(len(which)), np.empty((len(which), 3))
        for r in self.blocks(which):
            lml[r], lp[r], grad[r] = self.block(which[r], theta[r])
        return lml, lp, grad

    def blocks(self, which: np.ndarray) -> list[np.ndarray]:
        """The positions in ``which`` stacked together: by number of distinct inputs, ``BLOCK`` at a time."""
        sizes = self.u[which]
        out = []
        for u in np.unique(sizes):
            rows = np.nonzero(sizes == u)[0]
            out.extend(rows[s:s + BLOCK] for s in range(0, len(rows), BLOCK))
        return out

    def block(self, idx: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``objective`` of problems ``idx`` (the same number of distinct inputs) stacked at ``theta``."""
        D = np.stack([self.sets[self.xset[i]][0] for i in idx])
        w = np.stack([self.sets[self.xset[i]][1] for i in idx])
        z = np.stack([self.z[i] for i in idx])
        prior = np.stack([self.problems[i].prior for i in idx])
        with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
            return objective(D, w, z, self.ssw[idx], self.n[idx], theta, prior)


def _run_all(stack: Stack, owner: np.ndarray, x0: np.ndarray, options: dict, lockstep: bool) -> list[dict]:
    lo = np.stack([stack.problems[i].log_bounds[:, 0] for i in owner])
    hi = np.stack([stack.problems[i].log_bounds[:, 1] for i in owner])

    def fg(idx, X):   # minimise -(LML + log prior)
        lml, lp, grad = stack.evaluate(owner[idx], X)
        return -(lml + lp), -grad

    return (lbfgsb_lockstep if lockstep else lbfgsb_sequential)(fg, x0, lo, hi, options)


def fit_problems(problems: list[Problem], *, polish: bool = True, lockstep: bool | None = None,
                 cache: dict | None = None) -> list[Result]:
    """Fit every problem (all starts of all problems in one lock-step set of L-BFGS-B runs). Problems
    with the same key (training data, bounds, priors and starts: ``Problem.key``) are fitted once;
    ``cache`` ({key: Result}), when given, carries fits across calls (the banks of one stage run)."""
    cache = {} if cache is None else cache
    lockstep = setulb_available() if lockstep is None else lockstep
    todo = list({p.key: p for p in problems if p.key not in cache}.values())
    if todo:
        from threadpoolctl import threadpool_limits

        # One BLAS thread: the parallel axis is the stack of small matrices (its evaluations shared
        # out over processes: gp_workers), and BLAS threads on (n <= a few hundred) matrices only
        # spin against each other on a loaded machine.
        with threadpool_limits(1, user_api="blas"), shared(Stack(todo), BLOCK) as stack:
            cache.update(zip((p.key for p in todo), fit_stack(stack, polish, lockstep)))
    return [cache[p.key] for p in problems]


def fit_stack(stack, polish: bool, lockstep: bool) -> list[Result]:
    """Every start of every problem of ``stack`` in one lock-step set of L-BFGS-B runs, the best
    start per problem polished. ``stack``: ``problems`` (each with ``starts`` (S, p) and
    ``log_bounds`` (p, 2)) and ``evaluate(which, theta) -> (LML, log prior, gradient of their sum)``
    (the fit with an instance term brings its own)."""
    todo = stack.problems
    owner = np.concatenate([np.full(len(p.starts), i) for i, p in enumerate(todo)])
    x0 = np.concatenate([p.starts for p in todo])
    runs = _run_all(stack, owner, x0, DEFAULTS, lockstep)
    # Choose each problem's start on the objective at the run's final point (scipy's reported
    # fun can be a trial point's after a failed line search).
    ends = np.stack([r["x"] for r in runs])
    lml, lp, _ = stack.evaluate(owner, ends)
    obj = np.where(np.isfinite(lml), lml + lp, -np.inf)
    best = np.array([np.flatnonzero(owner == i)[np.argmax(obj[owner == i])] for i in range(len(todo))])
    theta = ends[best]
    if polish:
        fine = _run_all(stack, np.arange(len(todo)), theta, POLISH, lockstep)
        cand = np.stack([r["x"] for r in fine])
        l2, p2, _ = stack.evaluate(np.arange(len(todo)), cand)
        better = np.isfinite(l2) & (l2 + p2 >= obj[best])
        theta = np.where(better[:, None], cand, theta)
    lml, lp, _ = stack.evaluate(np.arange(len(todo)), theta)
    first = np.searchsorted(owner, np.arange(len(todo)))
    out = []
    for i in range(len(todo)):
        mine = [{k: r[k] for k in ("status", "message", "nit", "nfev")} for r, o in zip(runs, owner) if o == i]
        out.append(Result(theta[i].copy(), float(lml[i] + lp[i]), float(lml[i]), float(lp[i]), mine,
                          int(best[i] - first[i])))
    return out


def starts_for(theta0: np.ndarray, log_bounds: np.ndarray, restarts: int, random_state: int) -> np.ndarray:
    """The starts scikit-learn's fit makes: theta0, then ``restarts`` log-uniform draws in the
    bounds from ``RandomState(random_state)``."""
    rng = np.random.RandomState(random_state)
    draws = [rng.uniform(log_bounds[:, 0], log_bounds[:, 1]) for _ in range(restarts)]
    return np.vstack([np.asarray(theta0, float)[None]] + [d[None] for d in draws])


def prior_rows(priors: dict, i_ell: int, i_noise: int) -> np.ndarray:
    """(2, 2) rows (alpha, beta) of the length scale's and the noise's prior (NaN where none)."""
    out = np.full((2, 2), np.nan)
    for j, i in ((0, i_ell), (1, i_noise)):
        if i in priors:
            out[j] = (priors[i].alpha, priors[i].beta)
    if set(priors) - {i_ell, i_noise}:
        raise ValueError(f"prior_rows: the batched fit has priors on the length scale and the noise only, got {sorted(priors)}")
    return out
