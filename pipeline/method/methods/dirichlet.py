"""Dirichlet (Tchuiev & Indelman 2018): one Dirichlet per class over the classifier's whole
probability vector, the dropout samples fused as a posterior cloud
(``pipeline.method.dirichlet_fusion``). View-independent; not in the simulation, whose measurements
are GP scores, not probability vectors."""
from __future__ import annotations

import numpy as np

from pipeline.method import dirichlet_fusion as DF
from pipeline.method.names import DIRICHLET
from pipeline.method.method_base import FusionMethod, TrackInput, register


@register
class Dirichlet(FusionMethod):
    key = DIRICHLET
    label = "Dirichlet (Tchuiev & Indelman)"
    short = "Dirichlet"
    color = "#CC79A7"
    note = ("one Dirichlet distribution per class over the classifier's whole probability vector, fused over the "
            "dropout samples; ignores the viewpoint and the poses")
    needs = frozenset({"dirichlet", "probs"})
    uses_poses = False

    def fuse_with_extras(self, t: TrackInput) -> tuple[np.ndarray, dict]:
        """log E[λ] per step (K, C), and the cloud's std of λ (K, C) as ``dirichlet_std``."""
        log_mean, std = DF.fuse_dirichlet(t.dirichlet, t.probs, n_ss=t.n_ss, rng=t.rng)
        return log_mean, {"dirichlet_std": std}

    def fuse(self, t: TrackInput) -> np.ndarray:
        return self.fuse_with_extras(t)[0]

    def single_view(self, t: TrackInput) -> np.ndarray:
        return DF.single_view(t.dirichlet, t.probs)
