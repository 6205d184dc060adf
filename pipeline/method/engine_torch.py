"""The fusion engine's per-block work in torch float64 (a GPU, or torch on the CPU in the tests).

Same routes and factors as ``pipeline/method/engine.py`` (the plan is built once in numpy and
copied to the device): basis GPs by a GEMM with Qᵀ, exact GPs by kernel rows times the
precomputed L⁻¹; then batched Cholesky, L⁻¹ by a triangular solve, the conditional Gaussian of
every dropout sample and the recursion (``pipeline/method/fusion.py`` documents the algebra).
Results equal the numpy engine's to rounding (tests/test_engine_torch.py).
"""
from __future__ import annotations

import math
import threading
import weakref

import numpy as np

from pipeline.method import circle_basis as cb
from pipeline.method import engine
from pipeline.method.gp_instance import instance_term
from pipeline.method.student_t import log_const

_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()


class TorchPlan:
    def __init__(self, models, device: str):
        import torch

        self.torch, self.device = torch, torch.device(device)
        pl = engine.plan(models)
        t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=self.device)  # noqa: E731
        self.models, self.plan = models, pl
        self.P_max = pl.P_max
        # Test measurements carry σ_n² + δ² (GPClassModels.test_noise); the basis keeps the training σ_n².
        self.basis = [(i, c, f, pl.basis[c][f].P, t(cb.dense_q(pl.basis[c][f]).T), pl.basis[c][f].mean,
                       pl.basis[c][f].noise + float(models.test_variance[c, f]))
                      for i, (c, f) in enumerate(pl.members)]
        self.wbar = t(pl.wbar) if pl.members else None
        self._t = t
        self._exact: dict[int, dict] = {}
        self.amp, self.ell, self.noise, self.mean = (t(models.amplitude), t(models.length_scale),
                                                     t(models.test_noise), t(models.mean))


    def exact(self, c: int) -> dict:
        """Class c's exact-route factors on the device (made on first use)."""
        e = self._exact.get(c)
        if e is None:
            t, fc = self._t, self.models.factors()[c]
            e = dict(center=t(fc.center), T=t(fc.T), tsq=t(fc.tsq), alpha=t(fc.alpha),
                     linv=[t(self.plan.linv(c, f)) for f in range(self.models.n_components)])
            self._exact[c] = e
        return e


def torch_plan(models, device: str) -> TorchPlan:
    with _LOCK:
        per = _CACHE.setdefault(models, {})
        p = per.get(device)
    if p is None:
        p = TorchPlan(models, device)
        with _LOCK:
            per.setdefault(device, p)
    return p


def features(x, P: int):
    """``circle_basis.features`` on a tensor."""
    import torch

    return cb.fill_features(torch.empty((x.shape[0], P), dtype=x.dtype, device=x.device), x)


def predictive(tp: TorchPlan, X_np: np.ndarray):
    """mu (B, C, F, K), cov (B, C, F, K, K) as float64 tensors on the plan's device."""
    torch = tp.torch
    models = tp.models
    B, K, d = X_np.shape
    C, F = models.n_classes, models.n_components
    X = torch.as_tensor(np.ascontiguousarray(X_np), dtype=torch.float64, device=tp.device)
    flat = X.reshape(B * K, d)
    mu = torch.empty((B, C, F, K), dtype=torch.float64, device=tp.device)
    cov = torch.empty((B, C, F, K, K), dtype=torch.float64, device=tp.device)
    use_basis = tp.P_max > 0 and cb.unit_error(X_np.reshape(-1, d)) <= cb.UNIT_TOL
    eye = torch.eye(K, dtype=torch.float64, device=tp.device)
    done = set()
    if use_basis:
        Phi = features(flat / torch.linalg.norm(flat, dim=1, keepdim=True), tp.P_max)
        means = Phi @ tp.wbar
        for i, c, f, P, QT, m, sn2 in tp.basis:
            mu[:, c, f, :] = (means[:, i] + m).reshape(B, K)
            Z = (Phi[:, :P] @ QT).reshape(B, K, P)
            cov[:, c, f] = Z @ Z.transpose(1, 2) + sn2 * eye
            done.add((c, f))
    D2tt = None
    for c in range(C):
        fs = [f for f in range(F) if (c, f) not in done]
        if not fs:
            continue
        if D2tt is None:
            diff = X[:, :, None, :] - X[:, None, :, :]
            D2tt = (diff * diff).sum(-1)
        e = tp.exact(c)
        x = flat - e["center"]
        D2 = (x @ (-2.0 * e["T"].T) + (x * x).sum(1)[:, None] + e["tsq"][None, :]).clamp_min(0.0)
        N = D2.shape[1]
        for f in fs:
            ell, a = tp.ell[c, f], tp.amp[c, f]
            V = torch.exp(D2 * (-0.5 / (ell * ell)) + torch.log(a))
            mu[:, c, f, :] = (V @ e["alpha"][f] + tp.mean[c, f]).reshape(B, K)
            V = (V @ e["linv"][f].T).reshape(B, K, N)
            kk = a * torch.exp(D2tt * (-0.5 / (ell * ell))) + tp.noise[c, f] * eye
            inst = instance_term(models, c, f)
            if inst is not None:   # an unseen instance's deviation, shared by every view (gp_instance.py)
                kk = kk + inst[0] * torch.exp(D2tt * (-0.5 / (inst[1] * inst[1])))
            cov[:, c, f] = kk - V @ V.transpose(1, 2)
    return mu, cov


def _factor(tp: TorchPlan, cov):
    """L and M = L⁻¹; a non-positive-definite matrix is named by the numpy engine's check."""
    torch = tp.torch
    L, info = torch.linalg.cholesky_ex(cov)
    if bool((info != 0).any()):

        engine.named_cholesky(cov.cpu().numpy(), tp.models)
        raise ValueError("joint predictive covariance is not positive definite")  # pragma: no cover
    K = cov.shape[-1]
    eye = torch.eye(K, dtype=cov.dtype, device=cov.device).expand_as(L)
    return L, torch.linalg.solve_triangular(L, eye, upper=False)


def _recursion(ll, logp0):
    """ll (..., C, K, S) -> log P(c | H_k) (..., K, C): Eq. 24-26 in log space, as the numpy engine's
    ``kernels.recursion_mean`` with the step axis after the classes."""
    import torch

    *lead, C, K, S = ll.shape
    out = torch.empty(tuple(lead) + (K, C), dtype=ll.dtype, device=ll.device)
    logp = logp0.expand(tuple(lead) + (C,))
    for k in range(K):
        h = ll[..., k, :] + logp[..., None]
        h = h - torch.logsumexp(h, dim=-2, keepdim=True)
        logp = torch.logsumexp(h, dim=-1) - math.log(S)
        out[..., k, :] = logp
    return out


def _t_terms(resid2, nu: float):
    """The Student-t's log density terms (``pipeline.method.student_t``: the part that replaces the
    Gaussian's -resid2/2, with its constant) of squared standardized residuals ``resid2``."""
    import torch


    return -0.5 * (nu + 1.0) * torch.log1p(resid2 / nu) + log_const(nu)


def mwu_block(models, device: str, X, mu_z, v_z, samples, logp0, nu: float = 0.0) -> np.ndarray:
    """As ``fusion._mwu_block`` followed by the logsumexp over localization samples: (r, K, C)."""
    tp = torch_plan(models, device)
    torch = tp.torch
    r, n, K, d = X.shape
    C, F = models.n_classes, models.n_components
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=tp.device)  # noqa: E731
    mu, cov = predictive(tp, X.reshape(r * n, K, d))
    L, M = _factor(tp, cov)
    shape = (r, n, C, F, K)
    mu, L, M = mu.reshape(shape), L.reshape(shape + (K,)), M.reshape(shape + (K,))
    mu_zt = t(np.swapaxes(mu_z, -1, -2))[:, None, None]             # (r, 1, 1, F, K)
    v_zt = t(np.swapaxes(v_z, -1, -2))[:, None, None, :, :, None]   # (r, 1, 1, F, K, 1)
    y = (M @ (mu_zt - mu)[..., None])[..., 0]
    M2 = torch.tril(M * M, diagonal=-1)
    q = (M2 @ v_zt)[..., 0]
    Ld = torch.diagonal(L, dim1=-2, dim2=-1)
    var = Ld * Ld * (1.0 + q)
    cmean = mu_zt - Ld * y
    s = t(np.moveaxis(samples, -1, -3))[:, None, None]              # (r, 1, 1, F, K, S)
    resid = (s - cmean[..., None]) ** 2 / var[..., None]
    terms = _t_terms(resid, nu).sum(dim=-3) if nu else -0.5 * resid.sum(dim=-3)
    ll = terms - 0.5 * torch.log(var).sum(dim=-2)[..., None]
    out = _recursion(ll, t(logp0))                                   # (r, n, K, C)
    return torch.logsumexp(out, dim=1).cpu().numpy()


def mb_block(models, device: str, X, Z, logp0, nu: float = 0.0) -> np.ndarray:
    """As the numpy Model Based block: X (b, K, d), measurements Z (b, K, F) -> (b, K, C)."""
    tp = torch_plan(models, device)
    torch = tp.torch
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=tp.device)  # noqa: E731
    mu, cov = predictive(tp, X)
    L, M = _factor(tp, cov)
    resid = t(np.swapaxes(Z, -1, -2))[:, None] - mu
    y = (M @ resid[..., None])[..., 0]
    Ld = torch.diagonal(L, dim1=-2, dim2=-1)
    ll = ((_t_terms(y * y, nu) if nu else -0.5 * y * y) - torch.log(Ld)).sum(dim=-2)
    return _recursion(ll[..., None], t(logp0)).cpu().numpy()
