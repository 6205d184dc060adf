"""Expected information gain of a candidate view about the class (docs/planning.md).

EIG(v) = H(P(c)) - E_z[H(P(c | z))]: the expected reduction of the posterior's entropy (nats) by
the score vector z the view would give. z's predictive is a mixture over the candidate classes
(weighted by the current posterior) and over the belief's localization samples (uniform): for
class c and sample j, each score component is the class GP's marginal predictive at that sample's
view, N(mu_cj, s_cj) (noise included, components independent, as in the fusion). The posterior
after z uses the same mixture: P(c | z) ∝ P(c) · mean_j N(z; mu_cj, s_cj).

Monte Carlo with a fixed sample count M per class: z_{c,m} = mu_{c,j(m)} + sqrt(s_{c,j(m)}) eps_m
with j(m) = m mod N_x (stratified over the samples) and the same standard normals eps for every
candidate view (common random numbers: views are compared on the same draws). The log
likelihoods of all (draw, class, sample) triples come from two matrix products per view.
Planning approximates what fusion does exactly: it predicts one score vector per view from the
GP's marginal, ignoring the correlation with the views already taken.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.method.fusion import logsumexp


def standard_draws(n: int, n_components: int, seed) -> np.ndarray:
    """The fixed standard normals (M, F) of the Monte-Carlo estimate."""
    return np.random.default_rng(seed).standard_normal((int(n), int(n_components)))


def entropy(log_p: np.ndarray, axis: int = -1) -> np.ndarray:
    """Shannon entropy (nats) of normalised log probabilities along ``axis`` (0·log 0 = 0)."""
    p = np.exp(log_p)
    return -np.sum(np.where(p > 0, p * log_p, 0.0), axis=axis)


def predictive(models, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per view, sample, class and component the GP's marginal mean and variance: inputs
    (V, N, d) -> (V, N, C, F) each."""
    V, N, d = inputs.shape
    mu, var = models.marginal(inputs.reshape(V * N, d))
    C, F = mu.shape[1:]
    return mu.reshape(V, N, C, F), np.maximum(var, 1e-300).reshape(V, N, C, F)


def expected_entropies(mu: np.ndarray, var: np.ndarray, log_prior: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Posterior entropy after each Monte-Carlo draw: (V, C, M) for draws of class c (rows)."""
    V, N, C, F = mu.shape
    M = len(eps)
    j = np.arange(M) % N
    sd = np.sqrt(var)
    z = mu[:, j] + sd[:, j] * eps[None, :, None, :]             # (V, M, C, F): draw m of class c
    z = np.moveaxis(z, 2, 1).reshape(V, C * M, F)               # rows (c, m)
    inv = 1.0 / var.reshape(V, N * C, F)                        # columns (j, c')
    m_inv = mu.reshape(V, N * C, F) * inv
    const = np.sum(mu.reshape(V, N * C, F) * m_inv + np.log(var.reshape(V, N * C, F)), axis=-1)
    quad = (z * z) @ np.swapaxes(inv, 1, 2) - 2.0 * (z @ np.swapaxes(m_inv, 1, 2)) + const[:, None, :]
    ll = (-0.5 * quad).reshape(V, C * M, N, C)                  # log N(z; class c', sample j), up to 2π
    lmix = logsumexp(ll, axis=2) - math.log(N)                  # (V, CM, C'): mean over samples
    lp = lmix + log_prior
    lp = lp - logsumexp(lp, axis=-1, keepdims=True)
    return entropy(lp).reshape(V, C, M)


def expected_information_gain(models, inputs: np.ndarray, log_prior: np.ndarray, eps: np.ndarray,
                              return_se: bool = False):
    """EIG (nats) of each candidate view: inputs (V, N_x, d) are the GP inputs of the belief's
    localization samples at each view, ``log_prior`` (C,) the current log posterior, ``eps``
    the fixed standard normals (M, F). With ``return_se`` also the Monte-Carlo standard error."""
    lp0 = np.asarray(log_prior, float)
    mu, var = predictive(models, np.asarray(inputs, float))
    h = expected_entropies(mu, var, lp0, np.asarray(eps, float))       # (V, C, M)
    w = np.exp(lp0)
    gain = entropy(lp0) - np.einsum("c,vc->v", w, h.mean(axis=-1))
    if not return_se:
        return gain
    M = h.shape[-1]
    se = np.sqrt(np.einsum("c,vc->v", w ** 2, h.var(axis=-1, ddof=1) / M))
    return gain, se
