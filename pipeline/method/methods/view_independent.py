"""View-independent Gaussian class models: the ablation of "modelling the viewpoint" on the same
numbers as With Uncertainty and Model Based.

Per class and component, one Gaussian over all of the class's training views: the mean and the
sample variance (ddof 1) of the GP bank's own training targets (``GPClassModels.Y``), plus the
test-domain variance δ² the GP methods add to a test measurement (``GPClassModels.test_variance``),
floored at ``var_floor``. Each view is an independent measurement: the log posterior after step k
is the sum over views and components of the Gaussian log densities, normalised over the candidates.
The MC-dropout samples of a view are averaged into one measurement, as Model Based treats them
(``TrackInput.measurement``): the method models neither the pose nor the dropout spread, so the
paired difference With Uncertainty − this method measures the viewpoint model and the two
uncertainties together, on exactly the GP methods' components and candidates.
"""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import log_prior, logsumexp
from pipeline.method.method_base import FusionMethod, TrackInput, register

KEY = "view_independent"


def class_gaussians(models, var_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(C, F) means and variances over each class's training views (the bank's GP targets)."""
    mean = np.stack([y.mean(axis=1) for y in models.Y])
    var = np.stack([y.var(axis=1, ddof=1) if y.shape[1] > 1 else np.zeros(len(y)) for y in models.Y])
    return mean, np.maximum(var + models.test_variance, var_floor)


def view_loglik(z: np.ndarray, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
    """Σ_f log N(z_f; mean_cf, var_cf) for measurements z (K, F) -> (K, C)."""
    d = z[:, None, :] - mean[None]
    return -0.5 * np.sum(d * d / var + np.log(2.0 * np.pi * var), axis=-1)


@register
class ViewIndependent(FusionMethod):
    key = KEY
    label = "View-independent Gaussian"
    short = "View-independent"
    color = "#8C564B"   # not a class colour (labels.CLASS_COLORS) nor another method's
    note = ("one Gaussian per class and GP component over all training views (the GP methods' own components "
            "and training scores), views fused as independent, dropout samples averaged as in Model Based: "
            "the ablation of modelling the viewpoint")
    needs = frozenset({"gp"})
    uses_poses = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        mean, var = class_gaussians(t.gp, t.var_floor)
        cum = np.cumsum(view_loglik(t.measurement, mean, var), axis=0) + log_prior(None, len(mean))
        return cum - logsumexp(cum, axis=-1, keepdims=True)

    def single_view(self, t: TrackInput) -> np.ndarray:
        mean, var = class_gaussians(t.gp, t.var_floor)
        ll = view_loglik(t.measurement, mean, var)
        return ll - logsumexp(ll, axis=-1, keepdims=True)
