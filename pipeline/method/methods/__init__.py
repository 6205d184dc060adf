"""The built-in fusion methods, one file each; importing this package registers them in the order
tables and figures show them (``pipeline.method.registry``): the listed ones first, then any other
module of this folder in name order, so a new built-in method is its file alone."""
import importlib
import pkgutil

from pipeline.method.provider import providers

from pipeline.method.methods import with_uncertainty, model_based, simple_bayes  # noqa: F401
from pipeline.method.methods import attribution, dirichlet, view_independent  # noqa: F401
from pipeline.method.methods import instance_term, with_uncertainty_instance, model_based_instance  # noqa: F401
from pipeline.method.methods import student_t  # noqa: F401

LISTED = ("with_uncertainty", "model_based", "simple_bayes", "attribution", "dirichlet", "view_independent",
          "instance_term", "with_uncertainty_instance", "model_based_instance", "student_t")
# Discovered modules are not in the stages' static code key: registry.outside_fingerprint covers them.
DISCOVERED = tuple(sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name not in LISTED))
# The listed files' model providers are in the stages' code key too (the providers' registry loads this package).
providers().static = frozenset(f"{__name__}.{n}" for n in LISTED)
for _name in DISCOVERED:
    importlib.import_module(f"{__name__}.{_name}")
