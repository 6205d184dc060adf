"""A literal implementation of the heavy-tailed variants (``pipeline/method/student_t.py``), the
oracle of ``with_uncertainty_t`` and ``model_based_t``: written from the definition, independent of
the engine's closed form and kernels.

With Uncertainty, t: at step k, per class and component, the paper's Gaussian over the past
dropout samples, N(s; a + Ω s_p, Σ_s) with s_p ~ N(μ_z, diag(v_z)), has the marginal mean
a + Ω μ_z and variance Σ_s + Ω diag(v_z) Ωᵀ (formed here explicitly from ``gp_joint`` with Ω and
Σ_s by matrix inverses); the measurement model is the Student-t of ν degrees of freedom with that
location and squared scale. Model Based, t: the chain rule's conditional mean and variance, each
a t the same way. The recursion runs from step 0 for every k, in linear space, as
``literal_paper`` does.
"""
from __future__ import annotations

import math

import numpy as np

from tests.support.literal_paper import gp_joint


def t_pdf(x: float, loc: float, scale2: float, nu: float) -> float:
    """Student-t density, location ``loc``, squared scale ``scale2``, ν = ``nu``."""
    c = math.gamma((nu + 1) / 2) / (math.gamma(nu / 2) * math.sqrt(nu * math.pi * scale2))
    return c * (1 + (x - loc) ** 2 / (nu * scale2)) ** (-(nu + 1) / 2)


def _moments(XT, ST, m, amp, ell, sn2, c, i, track, k, past):
    """The step-k conditional of GP (c, i) given the past values ``past`` (k,): mean, variance,
    and Ω (for the dropout variance term)."""
    mu, cov = gp_joint(XT[c], ST[c][i], m[c, i], amp[c, i], ell[c, i], sn2[c, i], track[:k + 1])
    if k == 0:
        return mu[0], cov[0, 0], np.zeros(0)
    Omega = cov[k, :k] @ np.linalg.inv(cov[:k, :k])
    return mu[k] + Omega @ (past - mu[:k]), cov[k, k] - Omega @ cov[:k, k], Omega


def literal_uncertainty_t(XT, ST, m, amp, ell, sn2, rel_samples, dropout, nu, prior=None, var_floor=1e-6):
    """With Uncertainty, t, after every step: (K, C), the mean over localization samples."""
    Nx, K, _ = rel_samples.shape
    C, F = len(ST), ST[0].shape[0]
    out = np.zeros((K, C))
    for upto in range(K):
        for x in range(Nx):
            track = rel_samples[x]
            post = np.full(C, 1.0 / C) if prior is None else np.asarray(prior, float) / np.sum(prior)
            for k in range(upto + 1):
                lik = np.ones((C, len(dropout[k])))
                for c in range(C):
                    for i in range(F):
                        past = dropout[:k, :, i]
                        mu_z = past.mean(axis=1) if k else np.zeros(0)
                        v_z = np.maximum(((past - mu_z[:, None]) ** 2).mean(axis=1), var_floor) if k else np.zeros(0)
                        mean, var, Omega = _moments(XT, ST, m, amp, ell, sn2, c, i, track, k, mu_z)
                        var = var + Omega @ np.diag(v_z) @ Omega
                        lik[c] *= [t_pdf(s[i], mean, var, nu) for s in dropout[k]]
                new = np.zeros(C)
                for j in range(len(dropout[k])):
                    h = lik[:, j] * post
                    new += h / h.sum()
                post = new / len(dropout[k])
            out[upto] += post
        out[upto] /= Nx
    return out


def literal_model_based_t(XT, ST, m, amp, ell, sn2, track, meas, nu, prior=None):
    """Model Based, t: one pose-estimate track (K, d), one measurement (K, F) per step -> (K, C)."""
    K = len(track)
    C, F = len(ST), ST[0].shape[0]
    out = np.zeros((K, C))
    for upto in range(K):
        post = np.full(C, 1.0 / C) if prior is None else np.asarray(prior, float) / np.sum(prior)
        for k in range(upto + 1):
            lik = np.ones(C)
            for c in range(C):
                for i in range(F):
                    mean, var, _ = _moments(XT, ST, m, amp, ell, sn2, c, i, track, k, meas[:k, i])
                    lik[c] *= t_pdf(meas[k, i], mean, var, nu)
            post = lik * post
            post = post / post.sum()
        out[upto] = post
    return out
