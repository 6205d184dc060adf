"""Method keys: the stable strings under which every method's results are stored.

They live with the methods (not with the display labels in ``pipeline.evaluation.metrics.labels``) so that
the fusion engine can name its own progress bars without importing the evaluation protocol.
"""
from __future__ import annotations

WITH_UNCERTAINTY = "with_uncertainty"
MODEL_BASED = "model_based"
SIMPLE_BAYES = "simple_bayes"
DIRICHLET = "dirichlet"  # Tchuiev & Indelman 2018 (pipeline/method/dirichlet_fusion.py)
METHODS = (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES, DIRICHLET)
# Attribution variants of With Uncertainty (one ingredient each), evaluated beside the methods.
WU_POSES_ONLY = "with_uncertainty_poses_only"       # dropout samples replaced by their mean
WU_DROPOUT_ONLY = "with_uncertainty_dropout_only"   # no pose sampling: σ = 0, N_x = 1 inside the method
ATTRIBUTION = (WU_POSES_ONLY, WU_DROPOUT_ONLY)

# Short names for progress bars and table headers.
METHOD_SHORT = {WITH_UNCERTAINTY: "With Uncertainty", MODEL_BASED: "Model Based", SIMPLE_BAYES: "Simple Bayes",
                DIRICHLET: "Dirichlet", WU_POSES_ONLY: "Poses-only variant", WU_DROPOUT_ONLY: "Dropout-only variant"}
