"""Class GPs that know instances differ: a hierarchical viewpoint model (docs/design.md §5,
"Instances differ").

Per class c and component f a training view of instance i at direction θ scores

    s_i(θ) = m + g(θ) + h_i(θ) + ε,   g ~ GP(0, k_g),  h_i ~ GP(0, k_h) independent between instances,

with k_g = a·exp(-|x - x'|²/(2ℓ²)) the class kernel of ``pipeline.method.gp``, k_h = b·exp(-|x -
x'|²/(2λ²)) the instance kernel (a long λ is a per-instance constant offset) and ε white noise σ².
The training covariance of class c is ``K_g + B ∘ K_h + σ² I`` (B_jl = 1 when views j and l show
the same instance: block diagonal by instance). An unseen instance shares nothing with the training
instances, so the cross covariance of its views with the training views is k_g alone, and the joint
predictive over a track's views is the predictive of g plus k_h between every pair of views plus
the test noise:

    μ = m + K_g(X,T) H (S - m),   Σ = K_g(X,X) - K_g(X,T) H K_g(T,X) + K_h(X,X) + σ²I,
    H = (K_g(T,T) + B ∘ K_h(T,T) + σ²I)⁻¹.

``InstanceGPClassModels`` is a ``GPClassModels`` whose training factors (``factors``) use that H and
whose ``predict``/``marginal`` add k_h; every fusion engine built on them carries the term
(``pipeline/method/engine.py`` sends such GPs down the exact route and adds k_h there). A GP with
instance amplitude 0 (a class with one training instance) is the plain GP, bit for bit.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.method.gp import GPClassModels
from pipeline.method.bank_index import content_digest


def same_instance(labels: np.ndarray) -> np.ndarray:
    """B (N, N): 1.0 where two training views show the same instance."""
    lab = np.asarray(labels)
    return (lab[:, None] == lab[None, :]).astype(float)


class InstanceGPClassModels(GPClassModels):
    """``GPClassModels`` plus an instance term per (class, component).

    Extra attributes: ``instances`` (per class (N_c,) integer instance labels of the training
    views), ``instance_amplitude`` b (C, F) >= 0 (0: no instance term) and
    ``instance_length_scale`` λ (C, F) > 0.
    """

    def __init__(self, classes, components, X, Y, mean, amplitude, length_scale, noise, *,
                 instances: Sequence[np.ndarray], instance_amplitude, instance_length_scale,
                 component_names=None, meta=None):
        super().__init__(classes, components, X, Y, mean, amplitude, length_scale, noise,
                         component_names=component_names, meta=meta)
        C, F = self.n_classes, self.n_components
        if len(instances) != C:
            raise ValueError(f"InstanceGPClassModels: {C} classes but {len(instances)} instance label sets")
        self.instances = []
        for c, lab in enumerate(instances):
            lab = np.asarray(lab)
            if lab.shape != (len(self.X[c]),) or not np.issubdtype(lab.dtype, np.integer):
                raise ValueError(f"InstanceGPClassModels: class {self.classes[c]!r}: instance labels must be "
                                 f"({len(self.X[c])},) integers, got {lab.shape} {lab.dtype}")
            self.instances.append(lab.astype(np.int64))
        self.instance_amplitude = self._param(instance_amplitude, "instance_amplitude", C, F, positive=False)
        if np.any(self.instance_amplitude < 0):
            raise ValueError("InstanceGPClassModels: 'instance_amplitude' must be >= 0")
        self.instance_length_scale = self._param(instance_length_scale, "instance_length_scale", C, F)

    @classmethod
    def from_plain(cls, models: GPClassModels, instances, instance_amplitude, instance_length_scale
                   ) -> "InstanceGPClassModels":
        """``models`` with an instance term (its test-domain variance kept)."""
        out = cls(models.classes, models.components, models.X, models.Y, models.mean, models.amplitude,
                  models.length_scale, models.noise, instances=instances, instance_amplitude=instance_amplitude,
                  instance_length_scale=instance_length_scale, component_names=models.component_names,
                  meta=models.meta)
        out.test_variance = np.array(models.test_variance, dtype=float)
        return out

    def has_instance(self, c: int, f: int) -> bool:
        return bool(self.instance_amplitude[c, f] > 0)

    def instance_kernel(self, c: int, f: int, D2: np.ndarray) -> np.ndarray:
        """k_h from squared distances."""
        lam = self.instance_length_scale[c, f]
        return self.instance_amplitude[c, f] * np.exp(-D2 / (2.0 * lam * lam))

    def _copy(self, ci, fi) -> "InstanceGPClassModels":
        plain = super()._copy(ci, fi)
        idx = list(range(self.n_classes)[ci]) if isinstance(ci, slice) else list(ci)
        fidx = list(range(self.n_components)[fi]) if isinstance(fi, slice) else list(fi)
        sel = np.ix_(idx, fidx)
        return InstanceGPClassModels.from_plain(plain, [self.instances[i] for i in idx],
                                                self.instance_amplitude[sel], self.instance_length_scale[sel])

    def _train_cov(self, c: int, f: int, D2: np.ndarray) -> np.ndarray:
        # The plain factorisation's loop, each GP factorised once with its instance term in K.
        K = super()._train_cov(c, f, D2)
        if self.has_instance(c, f):
            K += same_instance(self.instances[c]) * self.instance_kernel(c, f, D2)
        return K

    def _describe(self, c: int, f: int) -> str:
        return f"{super()._describe(c, f)}, instance amplitude {self.instance_amplitude[c, f]:g}"

    def instance_parameters(self, c: int, f: int) -> tuple[float, float] | None:
        # predict's joint covariance takes the term through gp.predictive_covariance
        return instance_term(self, c, f)

    def marginal(self, X):
        mu, var = super().marginal(X)
        return mu, var + self.instance_amplitude

    def hyperparameters(self) -> dict:
        out = super().hyperparameters()
        for c, cls in enumerate(self.classes):
            for f, comp in enumerate(self.components):
                out[cls][str(comp)].update(instance_amplitude=float(self.instance_amplitude[c, f]),
                                           instance_length_scale=float(self.instance_length_scale[c, f]))
        return out

    def digest(self, c: int | None = None, f: int | None = None, *, trained_only: bool = False) -> str:
        parts = [super().digest(c, f, trained_only=trained_only)]
        for ci in range(self.n_classes) if c is None else [c]:
            fs = range(self.n_components) if f is None else [f]
            parts += [self.instances[ci], np.array([[self.instance_amplitude[ci, fi], self.instance_length_scale[ci, fi]]
                                                    for fi in fs])]
        return content_digest(*parts)


def instance_term(models: GPClassModels, c: int, f: int) -> tuple[float, float] | None:
    """(b, λ) of GP (c, f)'s instance term, or None (plain models, or amplitude 0)."""
    if isinstance(models, InstanceGPClassModels) and models.has_instance(c, f):
        return float(models.instance_amplitude[c, f]), float(models.instance_length_scale[c, f])
    return None
