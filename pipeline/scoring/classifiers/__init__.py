"""The classifiers ``classifier.arch`` can name: the registry (``registry``) and one entry module
each (``alexnet``, ``efficientnet_lite0``, ``torchvision_models`` for ``torchvision:<model>``). Any
other module of this folder is discovered on first use of the registry, and other packages add
theirs through the entry-point group ``viewfuse.classifiers`` (``pipeline.infra.registry``)."""
from pipeline.scoring.classifiers.registry import (REGISTRY, Classifier, UnknownClassifier, card_arch, check_config,
                                                   classifier, describe_card, display_of, names,
                                                   register_classifier, register_family, unregister_classifier)

# the listed built-ins register on import and are in the stages' code key by this import; a
# discovered module or an entry point enters the classifier stage's key by REGISTRY.outside_fingerprint
from pipeline.scoring.classifiers import alexnet, efficientnet_lite0, torchvision_models  # noqa: E402,F401

LISTED = ("alexnet", "efficientnet_lite0", "torchvision_models")
REGISTRY.static = frozenset(f"{__name__}.{n}" for n in LISTED)

__all__ = ["REGISTRY", "Classifier", "UnknownClassifier", "card_arch", "check_config", "classifier", "describe_card",
           "display_of", "names", "register_classifier", "register_family", "unregister_classifier"]
