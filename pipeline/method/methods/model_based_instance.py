"""Model Based on the class models with an instance term (``pipeline/method/gp_instance.py``): the
pose estimate taken as exact and one measurement per step, as Model Based, but the unseen
instance's deviation is shared by every view of the track. With the With Uncertainty variant it
attributes a gain to the instance term alone (both with and without pose and dropout sampling)."""
from __future__ import annotations

from pipeline.method.method_base import register
from pipeline.method.methods.instance_term import OnInstanceModels
from pipeline.method.methods.model_based import ModelBased
from pipeline.method.names import MB_INSTANCE


@register
class ModelBasedInstance(OnInstanceModels, ModelBased):
    key = MB_INSTANCE
    label = "Model Based, instances differ"
    short = "Model Based + instance"
    color = "#BB5566"   # not a class colour (metrics.labels.CLASS_COLORS)
    note = ("Model Based whose class models add a deviation of the unseen object from its class, shared by every "
            "view of the track: no localization or model uncertainty")

