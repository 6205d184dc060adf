"""A slow, literal implementation of Feldman & Indelman 2020, Eq. 13-40 (docs/design.md §5).

Written straight from the maths and independent of ``pipeline.method.fusion``: every GP prediction is
recomputed with an explicit inverse ``H``, every step forms ``Ω``, ``Σ_s⁻¹``, ``Σ_z⁻¹``, ``Σ_J``,
``μ_J`` explicitly and evaluates the paper's Gaussian integral term by term (not the closed form the
engine uses), and the posterior after step k is obtained by running the whole recursion again
from step 0. Probabilities are kept in linear space, as written in the paper. Only for tests and
the benchmark: it is O(K⁴) per localization sample and far slower than the engine.

Models are given as plain arrays so that nothing here depends on ``pipeline.method.gp``:
``XT[c]`` (N_c, d) training inputs of class c, ``ST[c]`` (F, N_c) training targets, and
``m, amp, ell, sn2`` (C, F) with k(x, x') = amp·exp(-|x - x'|² / (2 ell²)) plus white noise sn2.

``inst`` (optional, every function): the instance term of docs/design.md §5, "Instances differ", as
``(labels, b, lam)``: ``labels[c]`` (N_c,) the training views' instances, ``b, lam`` (C, F) the
instance kernel's amplitude and length scale (b = 0: none). Training views of one instance share
k_h; the test views are one unseen instance, so k_h joins their covariance and not the cross terms.
"""
from __future__ import annotations

import math

import numpy as np


def _kernel(A: np.ndarray, B: np.ndarray, amp: float, ell: float) -> np.ndarray:
    """Squared-exponential kernel by explicit differences (not the engine's expansion)."""
    diff = A[:, None, :] - B[None, :, :]
    return amp * np.exp(-np.sum(diff * diff, axis=-1) / (2.0 * ell * ell))


def gp_joint(XT, ST, m, amp, ell, sn2, X, inst=None):
    """Eq. 13-16 for one (class, component): mean (K,) and covariance (K, K) at inputs X.

    μ = m + K(X,X_T) H (S_T - m),  Σ = K(X,X) + σ_n² I - K(X,X_T) H K(X_T,X),
    H = (K(X_T,X_T) + σ_n² I)⁻¹; test measurements carry the same white noise σ_n².
    With ``inst = (labels (N,), b, lam)`` (one GP's): K(X_T,X_T) gains same-instance k_h, K(X,X) gains k_h.
    """
    KT, KX = _kernel(XT, XT, amp, ell), _kernel(X, X, amp, ell)
    if inst is not None and inst[1] > 0:
        labels, b, lam = inst
        KT = KT + (np.asarray(labels)[:, None] == np.asarray(labels)[None, :]) * _kernel(XT, XT, b, lam)
        KX = KX + _kernel(X, X, b, lam)
    H = np.linalg.inv(KT + sn2 * np.eye(len(XT)))
    Ks = _kernel(X, XT, amp, ell)
    mu = m + Ks @ H @ (ST - m)
    cov = KX + sn2 * np.eye(len(X)) - Ks @ H @ Ks.T
    return mu, cov


def _one(inst, c, i):
    """The instance term of GP (c, i) for ``gp_joint``, or None."""
    return None if inst is None else (inst[0][c], float(inst[1][c, i]), float(inst[2][c, i]))


def _normal_pdf(x: float, mean: float, var: float) -> float:
    return math.exp(-0.5 * (x - mean) ** 2 / var) / math.sqrt(2.0 * math.pi * var)


def _paper_integral(s, a, Omega, Sigma_s, mu_z, Sigma_z):
    """∫ N(s; a + Ω s_p, Σ_s) N(s_p; μ_z, Σ_z) ds_p written out as the paper does (Eq. 28-40).

    Completing the square in s_p: Σ_J⁻¹ = Ωᵀ Σ_s⁻¹ Ω + Σ_z⁻¹, μ_J = Σ_J (Ωᵀ Σ_s⁻¹ (s - a) + Σ_z⁻¹ μ_z);
    the Gaussian integral over s_p leaves (2π)^{k/2} |Σ_J|^{1/2} times the remaining exponent.
    """
    k = len(mu_z)
    Sigma_s_inv = np.linalg.inv(np.atleast_2d(Sigma_s))        # 1x1 here: one component at step k
    Sigma_z_inv = np.linalg.inv(Sigma_z)
    Omega = np.atleast_2d(Omega)                                # (1, k)
    r = np.atleast_1d(s - a)
    Sigma_J = np.linalg.inv(Omega.T @ Sigma_s_inv @ Omega + Sigma_z_inv)
    mu_J = Sigma_J @ (Omega.T @ Sigma_s_inv @ r + Sigma_z_inv @ mu_z)
    expo = -0.5 * (r @ Sigma_s_inv @ r + mu_z @ Sigma_z_inv @ mu_z - mu_J @ np.linalg.inv(Sigma_J) @ mu_J)
    norm = ((2 * math.pi) ** (-0.5) * np.linalg.det(np.atleast_2d(Sigma_s)) ** (-0.5)
            * (2 * math.pi) ** (-k / 2) * np.linalg.det(Sigma_z) ** (-0.5)
            * (2 * math.pi) ** (k / 2) * np.linalg.det(Sigma_J) ** 0.5)
    return float(norm * math.exp(expo))


def _likelihood_uncertainty(XT, ST, m, amp, ell, sn2, track, dropout, k, c, var_floor, inst=None):
    """P(s | c, past) for one localization sample's track at step k, for every dropout sample s
    of step k: array (N_s,)."""
    F = ST[c].shape[0]
    p = np.ones(len(dropout[k]))
    for i in range(F):  # components are independent (Eq. 17)
        mu, cov = gp_joint(XT[c], ST[c][i], m[c, i], amp[c, i], ell[c, i], sn2[c, i], track[:k + 1],
                           _one(inst, c, i))
        if k == 0:
            p *= [_normal_pdf(s[i], mu[0], cov[0, 0]) for s in dropout[k]]
            continue
        Sigma_past = cov[:k, :k]
        Sigma_kp = cov[k, :k]
        Omega = Sigma_kp @ np.linalg.inv(Sigma_past)            # Ω = Σ_{k,past} Σ_past⁻¹
        Sigma_s = cov[k, k] - Omega @ cov[:k, k]                # Σ_{k|past}
        a = mu[k] - Omega @ mu[:k]
        past = dropout[:k, :, i]                                # (k, N_s) past dropout samples
        mu_z = past.mean(axis=1)
        v_z = np.maximum(((past - mu_z[:, None]) ** 2).mean(axis=1), var_floor)  # ddof 0, floored
        p *= [_paper_integral(s[i], a, Omega, Sigma_s, mu_z, np.diag(v_z)) for s in dropout[k]]
    return p


def posterior_uncertainty_sample(XT, ST, m, amp, ell, sn2, track, dropout, upto, prior=None,
                                 var_floor=1e-6, inst=None):
    """P(c | H_upto) for one localization sample, recursion run from step 0 (Eq. 20-26)."""
    C = len(ST)
    post = np.full(C, 1.0 / C) if prior is None else np.asarray(prior, float) / np.sum(prior)
    for k in range(upto + 1):
        lik = np.array([_likelihood_uncertainty(XT, ST, m, amp, ell, sn2, track, dropout, k, c, var_floor, inst)
                        for c in range(C)])                     # (C, N_s)
        new = np.zeros(C)
        for j in range(len(dropout[k])):                        # h_c(s) normalised over c, per s
            h = lik[:, j] * post
            new += h / h.sum()
        post = new / len(dropout[k])
    return post


def literal_uncertainty(XT, ST, m, amp, ell, sn2, rel_samples, dropout, prior=None, var_floor=1e-6, inst=None):
    """Model with Uncertainty after every step: (K, C), the mean over localization samples (Eq. 42).

    Each step's posterior is recomputed from scratch (recursion from step 0, every GP prediction
    again), as a literal reading of the equations does.
    """
    Nx, K, _ = rel_samples.shape
    out = np.zeros((K, len(ST)))
    for k in range(K):
        for x in range(Nx):
            out[k] += posterior_uncertainty_sample(XT, ST, m, amp, ell, sn2, rel_samples[x], dropout,
                                                   k, prior, var_floor, inst)
        out[k] /= Nx
    return out


def literal_model_based(XT, ST, m, amp, ell, sn2, track, meas, prior=None, inst=None):
    """Model Based (Teacy et al.): one pose estimate track (K, d), one measurement (K, F) per step.

    P(z_k | c, z_past) = Π_i N(z_k; μ_k + Ω (z_past - μ_past), Σ_{k|past}); recursion from scratch.
    """
    K = len(track)
    C, F = len(ST), ST[0].shape[0]
    out = np.zeros((K, C))
    for upto in range(K):
        post = np.full(C, 1.0 / C) if prior is None else np.asarray(prior, float) / np.sum(prior)
        for k in range(upto + 1):
            lik = np.ones(C)
            for c in range(C):
                for i in range(F):
                    mu, cov = gp_joint(XT[c], ST[c][i], m[c, i], amp[c, i], ell[c, i], sn2[c, i],
                                       track[:k + 1], _one(inst, c, i))
                    if k == 0:
                        lik[c] *= _normal_pdf(meas[0, i], mu[0], cov[0, 0])
                        continue
                    Omega = cov[k, :k] @ np.linalg.inv(cov[:k, :k])
                    mean = mu[k] + Omega @ (meas[:k, i] - mu[:k])
                    var = cov[k, k] - Omega @ cov[:k, k]
                    lik[c] *= _normal_pdf(meas[k, i], mean, var)
            post = lik * post
            post = post / post.sum()
        out[upto] = post
    return out


def literal_view_independent(ST, dropout, test_var=None, prior=None, var_floor=1e-6):
    """The view-independent Gaussian baseline (not in the paper), from its
    definition: per class c and component i one Gaussian with the mean and the ddof-1 variance of
    the training targets ST[c][i] (plus the test-domain variance, floored); each step's measurement
    the mean of its dropout samples; P(c | z_0..k) ∝ P(c) Π_j Π_i N(z_ji; m_ci, v_ci), recomputed
    from step 0 for every k, in linear space. dropout (K, N_s, F) -> (K, C)."""
    C, K = len(ST), len(dropout)
    out = np.zeros((K, C))
    for upto in range(K):
        post = np.full(C, 1.0 / C) if prior is None else np.asarray(prior, float) / np.sum(prior)
        for k in range(upto + 1):
            for c in range(C):
                for i in range(ST[c].shape[0]):
                    t = list(ST[c][i])
                    m = sum(t) / len(t)
                    v = sum((x - m) ** 2 for x in t) / (len(t) - 1)
                    v = max(v + (0.0 if test_var is None else float(test_var[c][i])), var_floor)
                    z = sum(float(s[i]) for s in dropout[k]) / len(dropout[k])
                    post[c] *= _normal_pdf(z, m, v)
            post = post / post.sum()
        out[upto] = post
    return out
