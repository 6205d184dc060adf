"""With Uncertainty on the class models with an instance term (``pipeline/method/gp_instance.py``):
the same recursion over pose and dropout samples, where an unseen instance's deviation from its
class is one draw shared by every view of the track instead of independent noise per view. Applies
where the cell carries the instance bank (``TrackInput.gp_instance``); on classes of one training
instance it is With Uncertainty bit for bit."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.method.method_base import TrackInput, register
from pipeline.method.methods.with_uncertainty import WithUncertainty
from pipeline.method.names import WU_INSTANCE


@register
class WithUncertaintyInstance(WithUncertainty):
    key = WU_INSTANCE
    label = "With Uncertainty, instances differ"
    short = "With Uncertainty + instance"
    color = "#004488"   # not a class colour (metrics.labels.CLASS_COLORS)
    note = ("With Uncertainty whose class models add a deviation of the unseen object from its class, shared by "
            "every view of the track (fitted on the training instances)")
    needs = frozenset({"gp_instance"})
    simulation = False
    planning = False

    def fuse(self, t: TrackInput) -> np.ndarray:
        return super().fuse(replace(t, gp=t.gp_instance))

    def single_view(self, t: TrackInput) -> np.ndarray:
        return super().single_view(replace(t, gp=t.gp_instance))
