"""viewfuse's public Python API: the names a researcher uses to fit class models on their own
data, fuse their own track with any registered method, add a method, classifier, planner, metric
or dataset of their own (docs/extending.md), and evaluate a population. Everything else in the project (the
top-level ``pipeline``, ``loaders``, ``reports`` and ``stages`` packages) is internal and may change; import from here (docs/api.md).

    import viewfuse as vf
    models = vf.fit_models({"mug": (angles, scores), ...})
    log_post = vf.fuse("with_uncertainty", models, cameras=xy, object_xy=o, dropout=z, sigma=0.3, n_x=50)
"""
from __future__ import annotations
import pipeline.infra.decoder_limits  # noqa: F401,E402  OpenCV's decoder limits, set before any cv2 import

from viewfuse._check import check_install

check_install()

from pipeline.method.gp import GPClassModels  # noqa: E402
from pipeline.method.registry import FusionMethod, TrackInput, comparisons, unregister  # noqa: E402
from pipeline.method.provider import (Interval, ModelProvider, Section, Spread, TrainingViews,  # noqa: E402
                                      providers, register_provider, unregister_provider)
from pipeline.evaluation.metrics.spec import Metric, register_metric, unregister_metric  # noqa: E402
from pipeline.planning.planners import Planner, register_planner, unregister_planner  # noqa: E402
from pipeline.scoring.classifiers import Classifier, register_classifier, unregister_classifier  # noqa: E402
from viewfuse.scoring import mc_dropout_scores  # noqa: E402
from pipeline.infra.datasets import DatasetSource, Work, register_dataset, unregister_dataset  # noqa: E402
from loaders.real_imagery.turntable import TurntableConfig, TurntableSource  # noqa: E402
from loaders.image_gate import read_rgb as read_image  # noqa: E402
from pipeline.infra.config.fields import setting  # noqa: E402
from pipeline.infra.cost import Term  # noqa: E402
from viewfuse.api import evaluate_population, fit_models, fuse, method, track_metrics  # noqa: E402
from pipeline.infra.extension import ExtensionError  # noqa: E402
from viewfuse.extensions import Entry, classifiers, datasets, methods, metrics, planners, register  # noqa: E402
from viewfuse.check_extension import check_extension  # noqa: E402

__all__ = ["FusionMethod", "TrackInput", "register", "unregister", "methods", "method", "comparisons",
           "GPClassModels", "ModelProvider", "TrainingViews", "Section", "Spread", "Interval",
           "register_provider", "unregister_provider",
           "providers", "fit_models", "fuse", "track_metrics", "evaluate_population",
           "Classifier", "classifiers", "register_classifier", "unregister_classifier", "Planner", "register_planner",
           "unregister_planner", "Metric", "register_metric", "unregister_metric", "mc_dropout_scores",
           "DatasetSource", "Work", "datasets", "register_dataset", "unregister_dataset", "TurntableSource",
           "TurntableConfig", "read_image", "setting", "Term", "ExtensionError", "Entry", "planners", "metrics",
           "check_extension"]
