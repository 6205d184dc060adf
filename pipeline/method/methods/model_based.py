"""Model Based (Teacy et al.): the GP class models at the pose estimate taken as exact, on the mean
of the dropout samples (``pipeline.method.fusion.fuse_model_based``)."""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import fuse_model_based
from pipeline.method.names import MODEL_BASED
from pipeline.method.method_base import FusionMethod, TrackInput, register


@register
class ModelBased(FusionMethod):
    key = MODEL_BASED
    label = "Model Based (Teacy et al.)"
    short = "Model Based"
    color = "#D55E00"
    note = ("the same GP class models, evaluated at the estimated pose as if it were exact, on the mean of the "
            "dropout samples: no localization or model uncertainty")
    needs = frozenset({"gp"})
    simulation = True

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.estimates)
        return fuse_model_based(t.gp, t.inputs(t.estimates), np.broadcast_to(t.measurement, (r,) + t.measurement.shape),
                                return_log=True, progress=False)

    def single_view(self, t: TrackInput) -> np.ndarray:
        return fuse_model_based(t.gp, t.inputs(t.estimates[0][:, None, :]), t.measurement[:, None, :],
                                return_log=True, progress=False)[:, 0]

    def simulate(self, models, draws, sim) -> np.ndarray:
        return fuse_model_based(models, draws.estimates, draws.noised, progress=False)
