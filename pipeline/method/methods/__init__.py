"""The built-in fusion methods, one file each; importing this package registers the listed ones in
the order tables and figures show them (``pipeline.method.registry``); any other module of this
folder is imported, in name order, when a registry of this folder first loads
(``pipeline.infra.registry.Registry``: the one discovery), so a new built-in method is its file
alone."""
from pipeline.method.provider import providers

from pipeline.method.methods import with_uncertainty, model_based, simple_bayes  # noqa: F401
from pipeline.method.methods import attribution, dirichlet, view_independent  # noqa: F401
from pipeline.method.methods import instance_term, with_uncertainty_instance, model_based_instance  # noqa: F401
from pipeline.method.methods import student_t  # noqa: F401

LISTED = ("with_uncertainty", "model_based", "simple_bayes", "attribution", "dirichlet", "view_independent",
          "instance_term", "with_uncertainty_instance", "model_based_instance", "student_t")
# Modules found by the registry's discovery are not in the stages' static code key:
# registry.outside_fingerprint covers them. The listed files' model providers are in the stages'
# code key too (the providers' registry loads this package).
providers().static = frozenset(f"{__name__}.{n}" for n in LISTED)
