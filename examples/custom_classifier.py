"""A classifier of your own: one class, registered, then named by ``classifier.arch`` in a config
(the classifier and features stages build, card and score it like the built-in ones). Here
torchvision's MobileNetV3-Small, whose head has a Dropout before its last Linear layer: MC dropout
resamples that layer's mask, the trunk runs once per image. The weights are random, written to a
temporary .npz of plain arrays (nothing is downloaded). Run: python examples/custom_classifier.py

From a package of your own, the same class is an entry point in the group ``viewfuse.classifiers``
(docs/extending.md), so every process of a run finds it, Ray workers included."""
import tempfile
from pathlib import Path

import numpy as np
import torch

import viewfuse as vf


@vf.register_classifier
class SmallMobileNet(vf.Classifier):
    name = "mobilenet_small_example"                       # the classifier.arch value
    display = "MobileNetV3-Small (example)"
    architecture = "torchvision.models.mobilenet_v3_small"  # in the card, hence in the features' key
    mc_dropout_site = "the head's Dropout before its last Linear layer"

    def build(self, num_classes, dropout, drop_connect=0.0):
        from torchvision.models import mobilenet_v3_small

        return mobilenet_v3_small(weights=None, num_classes=num_classes, dropout=dropout)

    def last_linear_key(self):
        return "classifier.3.weight"


print("classifiers:", ", ".join(vf.classifiers()))
C, N_S = 4, 30
net = SmallMobileNet().build(C, 0.5)
torch.manual_seed(0)
images = torch.randn(3, 3, 96, 96).numpy()
# random weights: set the batch-norm statistics from a batch of noise (else the signal vanishes in
# eval mode) and widen the last layer, so the classes differ
for m in net.modules():
    if isinstance(m, torch.nn.BatchNorm2d):
        m.momentum = None                 # the running statistics: this batch's, not a 1 % step toward them
with torch.no_grad():
    net.classifier[3].weight.mul_(30.0)
    net.train()(torch.randn(32, 3, 96, 96))
with tempfile.TemporaryDirectory() as tmp:
    weights = Path(tmp) / "weights.npz"
    np.savez(weights, **{k: v.numpy() for k, v in net.state_dict().items()})
    det, mc = vf.mc_dropout_scores("mobilenet_small_example", weights, images, num_classes=C, dropout=0.5,
                                   n_samples=N_S)
for i in range(len(images)):
    top = int(det[i].argmax())
    s = mc[i, :, top]
    half = 1.96 * s.std(ddof=1) / np.sqrt(N_S)
    print(f"image {i}: P(class {top}) deterministic {det[i, top]:.3f}; MC-dropout mean {s.mean():.3f}, "
          f"95 % CI over the {N_S} dropout samples [{s.mean() - half:.3f}, {s.mean() + half:.3f}]")
vf.unregister_classifier("mobilenet_small_example")
