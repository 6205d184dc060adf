"""The metric parameters tests use: the config's defaults (``evaluate.confident_threshold``,
``evaluate.ece_bins``), so a test states no threshold of its own unless it varies it."""
from pipeline.evaluation.metrics.spec import Params
from pipeline.infra.config.evaluation import EvaluateConfig

PARAMS = Params.of(EvaluateConfig())
