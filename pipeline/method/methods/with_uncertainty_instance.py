"""With Uncertainty on the class models with an instance term (``pipeline/method/gp_instance.py``):
the same recursion over pose and dropout samples, where an unseen instance's deviation from its
class is one draw shared by every view of the track instead of independent noise per view. Applies
where the cell carries those models (its provider, ``instance_term.py``); on classes of one training
instance it is With Uncertainty bit for bit. Planning's belief may keep it (``Belief(..., provided=...)``)."""
from __future__ import annotations

from pipeline.method.method_base import register
from pipeline.method.methods.instance_term import OnInstanceModels
from pipeline.method.methods.with_uncertainty import WithUncertainty
from pipeline.method.names import WU_INSTANCE


@register
class WithUncertaintyInstance(OnInstanceModels, WithUncertainty):
    key = WU_INSTANCE
    label = "With Uncertainty, instances differ"
    short = "With Uncertainty + instance"
    color = "#004488"   # not a class colour (metrics.labels.CLASS_COLORS)
    note = ("With Uncertainty whose class models add a deviation of the unseen object from its class, shared by "
            "every view of the track (fitted on the training instances)")

