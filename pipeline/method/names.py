"""The built-in methods' keys: the stable strings under which their results are stored, for code
that names one of them (the simulation's claims). Everything else about a
method (label, colour, what it needs, how it fuses) is its class in ``pipeline.method.methods``;
the list of methods is ``pipeline.method.registry.methods()``.
"""
from __future__ import annotations

WITH_UNCERTAINTY = "with_uncertainty"
MODEL_BASED = "model_based"
SIMPLE_BAYES = "simple_bayes"
WU_INSTANCE = "with_uncertainty_instance"   # on the class models with an instance term (their provider's)
MB_INSTANCE = "model_based_instance"
# summary.json's block of the two against themselves without the term (population's ablations)
INSTANCE_BLOCK = "instance_term"
# Attribution variants of With Uncertainty (one ingredient each), evaluated beside the methods.
WU_POSES_ONLY = "with_uncertainty_poses_only"       # dropout samples replaced by their mean
WU_DROPOUT_ONLY = "with_uncertainty_dropout_only"   # no pose sampling: σ = 0, N_x = 1 inside the method
ATTRIBUTION = (WU_POSES_ONLY, WU_DROPOUT_ONLY)
# The heavy-tailed variants (pipeline/method/student_t.py): a Student-t around the same predictive.
WU_T = "with_uncertainty_t"
MB_T = "model_based_t"
