"""The built-in fusion methods, one file each; importing this package registers them in the order
tables and figures show them (``pipeline.method.registry``)."""
from pipeline.method.methods import with_uncertainty, model_based, simple_bayes  # noqa: F401
from pipeline.method.methods import attribution, dirichlet  # noqa: F401
