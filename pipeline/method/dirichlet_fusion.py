"""Dirichlet fusion of MC-dropout probability vectors: the posterior-cloud recursion of Tchuiev &
Indelman 2018, Algorithm 1 (docs/design.md §5, "Dirichlet").

The state after step k is a cloud of posterior class-probability vectors λ over the C candidates
(one per combination of dropout samples kept so far), held as log λ. A view's dropout cloud
{γ_t} (N_s vectors) gives log likelihoods ``ℓ_t(c) = ln Dir(γ_t; θ_c)``; every pair (previous
point λ_i, new sample γ_t) yields ``λ' ∝ λ_i ⊙ exp(ℓ_t)``, and the M·N_s new points are
subsampled, uniformly without replacement, to at most N_ss. The step's output is the cloud's mean
E[λ] (the posterior P(c | z_1:k)) and its standard deviation per class.

Poses play no part: the method is view-independent, which is what it is evaluated for.
"""
from __future__ import annotations

import math

import numpy as np

from pipeline.method.dirichlet import DirichletModels
from pipeline.method.fusion import log_prior, logsumexp


def _normalise(log_lam: np.ndarray) -> np.ndarray:
    return log_lam - logsumexp(log_lam, axis=-1, keepdims=True)


def cloud_update(log_cloud: np.ndarray, loglik: np.ndarray, n_ss: int, rng: np.random.Generator | None) -> np.ndarray:
    """One step: cloud (M, C) of log λ and a view's log likelihoods (N_s, C) -> the new cloud.

    Pair (i, t) is row ``i·N_s + t`` before subsampling; when M·N_s <= n_ss every pair is kept in
    that order and ``rng`` is not used (so a large n_ss is the exact all-pairs recursion).
    """
    M, C = log_cloud.shape
    S = loglik.shape[0]
    pairs = _normalise((log_cloud[:, None, :] + loglik[None, :, :]).reshape(M * S, C))
    if M * S <= n_ss:
        return pairs
    if rng is None:
        raise ValueError("cloud_update: subsampling needs a random generator")
    keep = np.sort(rng.choice(M * S, size=n_ss, replace=False))
    return pairs[keep]


def cloud_moments(log_cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(log E[λ], std λ) over the cloud's points, per class; the mean in log space (no underflow)."""
    log_mean = logsumexp(log_cloud, axis=0) - math.log(len(log_cloud))
    return log_mean, np.exp(log_cloud).std(axis=0)


def fuse_dirichlet(models: DirichletModels, samples: np.ndarray, *, n_ss: int, rng: np.random.Generator | None,
                   prior=None) -> tuple[np.ndarray, np.ndarray]:
    """The recursion along one track: dropout probability vectors (K, N_s, D) -> per step the log
    posterior log E[λ] (K, C) and the cloud's std of λ (K, C). The cloud starts as one point,
    the prior (uniform when None)."""
    samples = np.asarray(samples, float)
    if samples.ndim != 3:
        raise ValueError(f"fuse_dirichlet: samples must be (K, N_s, D), got {samples.shape}")
    if n_ss < 1:
        raise ValueError(f"fuse_dirichlet: n_ss must be >= 1, got {n_ss}")
    C = len(models.classes)
    loglik = models.log_likelihood(samples)                       # (K, N_s, C)
    cloud = log_prior(prior, C)[None, :]
    K = samples.shape[0]
    log_mean, std = np.empty((K, C)), np.empty((K, C))
    for k in range(K):
        cloud = cloud_update(cloud, loglik[k], n_ss, rng)
        log_mean[k], std[k] = cloud_moments(cloud)
    return log_mean, std


def single_view(models: DirichletModels, samples: np.ndarray, prior=None) -> np.ndarray:
    """Each view alone (K, N_s, D) -> log E[λ] (K, C): the mean over its samples of the one-step
    posteriors (no subsampling: a single step has N_s points)."""
    loglik = models.log_likelihood(np.asarray(samples, float))    # (K, N_s, C)
    one = _normalise(loglik + log_prior(prior, loglik.shape[-1]))
    return logsumexp(one, axis=1) - math.log(loglik.shape[1])
