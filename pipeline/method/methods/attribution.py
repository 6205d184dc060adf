"""With Uncertainty with one ingredient each (the attribution variants, run with
``evaluate.attribution``): *poses only* (each step's dropout samples replaced by their mean) and
*dropout only* (no pose sampling: the estimates themselves, N_x = 1)."""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import fuse_with_uncertainty
from pipeline.method.names import WU_DROPOUT_ONLY, WU_POSES_ONLY
from pipeline.method.method_base import FusionMethod, TrackInput, register


@register
class PosesOnly(FusionMethod):
    key = WU_POSES_ONLY
    label = "With Uncertainty, poses only (dropout samples -> their mean)"
    short = "Poses-only variant"
    color = "#6699CC"
    note = "With Uncertainty with the dropout samples replaced by their mean"
    attribution = True
    uses_dropout = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.samples)
        mean_only = t.dropout.mean(axis=1, keepdims=True)                  # (K, 1, F)
        return fuse_with_uncertainty(t.gp, t.inputs(t.samples), np.broadcast_to(mean_only, (r,) + mean_only.shape),
                                     var_floor=t.var_floor, return_log=True, progress=False)


@register
class DropoutOnly(FusionMethod):
    key = WU_DROPOUT_ONLY
    label = "With Uncertainty, dropout only (no pose sampling)"
    short = "Dropout-only variant"
    color = "#994F00"
    note = "With Uncertainty without pose sampling (it trusts the pose estimate)"
    attribution = True

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.estimates)
        return fuse_with_uncertainty(t.gp, t.inputs(t.estimates[:, None]),
                                     np.broadcast_to(t.dropout, (r,) + t.dropout.shape),
                                     var_floor=t.var_floor, return_log=True, progress=False)
