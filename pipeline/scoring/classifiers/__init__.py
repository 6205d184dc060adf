"""The classifiers ``classifier.arch`` can name: the registry (``registry``) and one entry module
each (``alexnet``, ``efficientnet_lite0``, ``torchvision_models`` for ``torchvision:<model>``)."""
from pipeline.scoring.classifiers.registry import (Classifier, UnknownClassifier, card_arch, check_config,
                                                   classifier, describe_card, display_of, names,
                                                   register_classifier, register_family)

# the built-in entries register themselves on import
from pipeline.scoring.classifiers import alexnet, efficientnet_lite0, torchvision_models  # noqa: E402,F401

__all__ = ["Classifier", "UnknownClassifier", "card_arch", "check_config", "classifier", "describe_card",
           "display_of", "names", "register_classifier", "register_family"]
