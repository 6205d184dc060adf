"""With Uncertainty (Feldman & Indelman 2020): the GP class models averaged over the pose samples and
the MC-dropout samples (``pipeline.method.fusion.fuse_with_uncertainty``)."""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import fuse_with_uncertainty
from pipeline.method.names import WITH_UNCERTAINTY
from pipeline.method.method_base import FusionMethod, TrackInput, register


@register
class WithUncertainty(FusionMethod):
    key = WITH_UNCERTAINTY
    label = "With Uncertainty (Feldman & Indelman)"
    short = "With Uncertainty"
    color = "#0072B2"
    note = ("the paper's method: one GP per class and score component over the viewing direction; it averages "
            "over sampled camera poses (the localization noise) and over the classifier's dropout samples "
            "(model uncertainty)")
    needs = frozenset({"gp"})
    simulation = True
    planning = True

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.samples)
        return fuse_with_uncertainty(t.gp, t.inputs(t.samples), np.broadcast_to(t.dropout, (r,) + t.dropout.shape),
                                     var_floor=t.var_floor, return_log=True, progress=False)

    def fuse_tracks(self, t: TrackInput) -> np.ndarray:
        return fuse_with_uncertainty(t.gp, t.inputs(t.samples), t.dropout, var_floor=t.var_floor, return_log=True,
                                     progress=False, threads=t.threads)

    def single_view(self, t: TrackInput) -> np.ndarray:
        pos = t.estimates[0][:, None, None, :]                             # (K, N_x=1, 1, 2)
        return fuse_with_uncertainty(t.gp, t.inputs(pos), t.dropout[:, None], var_floor=t.var_floor,
                                     return_log=True, progress=False)[:, 0]

    def simulate(self, models, draws, sim) -> np.ndarray:
        return fuse_with_uncertainty(models, draws.loc_samples, draws.samples, var_floor=sim.variance_floor,
                                     progress=False)
