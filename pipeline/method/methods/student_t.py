"""With Uncertainty and Model Based with a heavy-tailed measurement model (``pipeline/method/student_t.py``):
each step's conditional predictive of a score component a Student-t of ν degrees of freedom
instead of the Gaussian, with the same location and squared scale. ν is the GP bank's
``tail_df[key]``, fitted per cross-fitting fold on the other folds' labelled crops
(``evaluate.likelihood_tail = "student_t"``, ``pipeline.evaluation.domain.tails``); where the
cell's models carry none the methods do not apply (the default: no run changes)."""
from __future__ import annotations

import numpy as np

from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty
from pipeline.method.method_base import TrackInput, register
from pipeline.method.methods.model_based import ModelBased
from pipeline.method.methods.with_uncertainty import WithUncertainty
from pipeline.method.names import MB_T, WU_T


class _Tailed:
    """A method on the GP bank that reads its ν from ``t.gp.tail_df``."""
    key: str

    def applies(self, t: TrackInput) -> bool:
        return super().applies(t) and self.key in getattr(t.gp, "tail_df", {})

    def nu(self, t: TrackInput) -> float:
        return t.gp.tail_df[self.key]


@register
class WithUncertaintyT(_Tailed, WithUncertainty):
    key = WU_T
    label = "With Uncertainty, Student-t likelihood"
    short = "With Uncertainty (t)"
    color = "#4477AA"   # not a class colour (metrics.labels.CLASS_COLORS) nor another method's
    note = ("With Uncertainty with each step's predictive a Student-t around the GP predictive (its degrees of "
            "freedom fitted on the other folds' labelled crops): one misfit component cannot veto a class")
    simulation = False
    planning = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.samples)
        return fuse_with_uncertainty(t.gp, t.inputs(t.samples), np.broadcast_to(t.dropout, (r,) + t.dropout.shape),
                                     var_floor=t.var_floor, return_log=True, progress=False, nu=self.nu(t))

    def single_view(self, t: TrackInput) -> np.ndarray:
        pos = t.estimates[0][:, None, None, :]
        return fuse_with_uncertainty(t.gp, t.inputs(pos), t.dropout[:, None], var_floor=t.var_floor,
                                     return_log=True, progress=False, nu=self.nu(t))[:, 0]


@register
class ModelBasedT(_Tailed, ModelBased):
    key = MB_T
    label = "Model Based, Student-t likelihood"
    short = "Model Based (t)"
    color = "#EE7733"   # not a class colour nor another method's
    note = ("Model Based with each step's predictive a Student-t around the GP predictive (degrees of freedom "
            "fitted on the other folds' labelled crops)")
    simulation = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        r = len(t.estimates)
        return fuse_model_based(t.gp, t.inputs(t.estimates), np.broadcast_to(t.measurement, (r,) + t.measurement.shape),
                                return_log=True, progress=False, nu=self.nu(t))

    def single_view(self, t: TrackInput) -> np.ndarray:
        return fuse_model_based(t.gp, t.inputs(t.estimates[0][:, None, :]), t.measurement[:, None, :],
                                return_log=True, progress=False, nu=self.nu(t))[:, 0]
