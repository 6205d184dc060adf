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


class RingTable:
    """The marginal predictive on the unit circle, tabulated at ``n`` evenly spaced angles once per
    model set and interpolated linearly in the angle: a planning decision then costs no GP
    prediction. Linear interpolation errs by at most h²/8·max|f''| ≈ 4e-4·amplitude at the
    default n = 2048 and the smallest length scale the hyperprior allows (0.052, docs/design.md §5)."""

    def __init__(self, models, n: int = 2048):
        th = np.arange(n) * (2 * np.pi / n)
        ring = np.stack([np.cos(th), np.sin(th)], -1)
        C, F = models.n_classes, models.n_components
        self.n = n
        self.mu = np.empty((n + 1, C, F))
        self.var = np.empty((n + 1, C, F))
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1, user_api="blas"):   # small products: BLAS threads only contend
            for c in range(C):
                T, Y = models.X[c], models.Y[c]
                D2 = np.maximum(np.sum(ring ** 2, 1)[:, None] + np.sum(T ** 2, 1)[None] - 2 * ring @ T.T, 0.0)
                for f in range(F):
                    # the GP's kernel a·exp(-d²/(2ℓ²)) (docs/design.md §5) on the ring's distances
                    k = models.amplitude[c, f] * np.exp(-D2 / (2 * models.length_scale[c, f] ** 2))   # (n, N)
                    H = np.linalg.inv(models.kernel(c, f, T, T) + models.noise[c, f] * np.eye(len(T)))
                    H = 0.5 * (H + H.T)
                    self.mu[:n, c, f] = models.mean[c, f] + k @ (H @ (Y[f] - models.mean[c, f]))
                    self.var[:n, c, f] = (models.amplitude[c, f] + models.test_noise[c, f]
                                          - np.einsum("ij,ij->i", k @ H, k))
        self.mu[n], self.var[n] = self.mu[0], self.var[0]                            # wrap around
        np.maximum(self.var, 1e-300, out=self.var)

    def __call__(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """inputs (..., 2) unit vectors -> mean, variance (..., C, F)."""
        t = np.mod(np.arctan2(inputs[..., 1], inputs[..., 0]), 2 * np.pi) * (self.n / (2 * np.pi))
        i = np.minimum(t.astype(np.int64), self.n - 1)
        w = (t - i)[..., None, None]
        return ((1 - w) * self.mu[i] + w * self.mu[i + 1], (1 - w) * self.var[i] + w * self.var[i + 1])


# Bytes one chunk of draws may take: the (V, C*m, N, C) log-likelihoods and their temporaries grow
# with plan.eig_samples, so the draws are processed in chunks and memory stays flat.
CHUNK_BYTES = 64 * 2 ** 20


def draws_per_chunk(V: int, N: int, C: int, chunk_bytes: float = CHUNK_BYTES) -> int:
    """Draws per chunk so that ~5 float64 (V, C, N, C) arrays per draw fit in ``chunk_bytes``."""
    return max(1, int(chunk_bytes // (5 * 8 * V * C * N * C)))


def expected_entropies(mu: np.ndarray, var: np.ndarray, log_prior: np.ndarray, eps: np.ndarray,
                       offset: int = 0) -> np.ndarray:
    """Posterior entropy after each Monte-Carlo draw: (V, C, M) for draws of class c (rows).
    ``offset``: the index of ``eps[0]`` among all draws (it picks the localization sample)."""
    V, N, C, F = mu.shape
    M = len(eps)
    j = (offset + np.arange(M)) % N
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
                              return_se: bool = False, table: RingTable | None = None):
    """EIG (nats) of each candidate view: inputs (V, N_x, d) are the GP inputs of the belief's
    localization samples at each view, ``log_prior`` (C,) the current log posterior, ``eps``
    the fixed standard normals (M, F). ``table``: the predictive from a ``RingTable`` instead of
    the GPs. With ``return_se`` also the Monte-Carlo standard error."""
    lp0 = np.asarray(log_prior, float)
    x = np.asarray(inputs, float)
    mu, var = predictive(models, x) if table is None else table(x)
    eps = np.asarray(eps, float)
    step = draws_per_chunk(*mu.shape[:3])
    h = np.concatenate([expected_entropies(mu, var, lp0, eps[a:a + step], offset=a)
                        for a in range(0, len(eps), step)], axis=-1)     # (V, C, M)
    w = np.exp(lp0)
    gain = entropy(lp0) - np.einsum("c,vc->v", w, h.mean(axis=-1))
    if not return_se:
        return gain
    M = h.shape[-1]
    se = np.sqrt(np.einsum("c,vc->v", w ** 2, h.var(axis=-1, ddof=1) / M))
    return gain, se
