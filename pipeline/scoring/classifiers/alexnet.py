"""``alexnet``: torchvision's AlexNet with the dropout p a setting, trained here on the synthetic
source domain or loaded from ImageNet / a file (``pipeline.scoring.alexnet``). MC dropout: the two
Dropout layers of its ``classifier`` head; the trunk (``features -> avgpool -> flatten``) runs once."""
from __future__ import annotations

from pipeline.scoring.classifiers.registry import Classifier, register_classifier


@register_classifier
class AlexNet(Classifier):
    key = "alexnet"
    label = "torchvision's AlexNet"
    architecture = "torchvision.models.alexnet"
    trains = True
    imagenet = True
    channels_last_scoring = True   # within 1e-7 here; EfficientNet-Lite0's depthwise kernels move scores ~3e-6

    def build(self, num_classes, dropout, drop_connect=0.0):
        from pipeline.scoring.alexnet import build_alexnet  # heavy: torch

        if drop_connect:
            raise ValueError("drop_connect is an EfficientNet-Lite0 setting; AlexNet has no residual blocks")
        return build_alexnet(num_classes, dropout)

    def last_linear_key(self):
        return "classifier.6.weight"

    def for_training(self, num_classes, dropout, seed):
        from pipeline.scoring.alexnet import build_alexnet, init_for_training  # heavy: torch

        return init_for_training(build_alexnet(num_classes, dropout), seed)

    def early_forward(self):
        from pipeline.scoring.alexnet import compact_forward  # heavy: torch

        return compact_forward

    def imagenet_location(self):
        from pipeline.scoring.alexnet import IMAGENET_FILE, imagenet_dir  # heavy: torch

        return imagenet_dir() / IMAGENET_FILE

    def imagenet_file(self):
        from pipeline.scoring.alexnet import imagenet_checkpoint  # heavy: torch

        return imagenet_checkpoint()

    def output_names(self, n):
        from pipeline.scoring.alexnet import imagenet_names  # heavy: torch

        return imagenet_names(n)

    def card_extra(self, c):
        return {}  # AlexNet's cards (and their hashes) stay as before the arch key existed

    def describe(self, card):
        if card.get("weights") == "imagenet":
            return "classifier: torchvision's ImageNet AlexNet (IMAGENET1K_V1), no held-out accuracy on these objects"
        return f"classifier: AlexNet weights from {card.get('weights_file', 'a file')}"
