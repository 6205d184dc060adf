"""``torchvision:<model>``: any torchvision classification architecture by name (``resnet18``,
``mobilenet_v3_small``, ...), built with random weights and loaded from ``classifier.path`` (an
``.npz`` of plain arrays or a tensor-only torch file; the card records its sha256). Nothing is
downloaded, so ``weights = 'imagenet'`` is not offered.

MC-dropout site, declared per network from its head (the last top-level child holding the last
Linear layer, e.g. ``fc``, ``classifier``, ``heads``):
- a head with Dropout layers (VGG, MobileNet, EfficientNet): those layers, p = ``classifier.dropout``;
  when the only Dropout sits before the last Linear, the trunk runs once per crop (head-only);
- a head without Dropout (ResNet, DenseNet, RegNet): a Dropout(p) inserted before its final Linear
  (it holds no weights, so torchvision's state dicts load unchanged).
The trunk is the network up to its head's input; any Dropout inside it stays off (eval mode).
A head of other layers (ConvNeXt's LayerNorm2d) is refused with the layer named.
"""
from __future__ import annotations

from pipeline.scoring.classifiers.registry import Classifier, UnknownClassifier, register_family

FAMILY = "torchvision"
# Layers a head may hold besides Dropout and Linear: they act on one feature row at a time.
ROW_LAYERS = ("ReLU", "ReLU6", "Hardswish", "SiLU", "GELU", "Tanh", "Identity", "Flatten")


class _HeadReached(Exception):
    """Stops the forward pass at the head: the trunk's output is the head's input."""


def _head(model):
    """(attribute, module) of the last top-level child that holds the model's last Linear layer."""
    from torch import nn

    last = None
    for attr, child in model.named_children():
        if isinstance(child, nn.Linear) or any(isinstance(m, nn.Linear) for m in child.modules()):
            last = (attr, child)
    if last is None:
        raise ValueError("no Linear layer: not a classification network")
    return last


class TorchvisionClassifier(Classifier):
    def __init__(self, model: str):
        self.model = model
        self.name = f"{FAMILY}:{model}"
        self.display = f"torchvision's {model}"
        self.key, self.label = self.name, self.display
        self.architecture = f"torchvision.models.{model}"

    def build(self, num_classes, dropout, drop_connect=0.0):
        import torch
        from torch import nn
        from torchvision.models import get_model

        if drop_connect:
            raise ValueError(f"drop_connect is an EfficientNet-Lite0 setting, not one of {self.name}")
        if num_classes < 1 or not 0.0 <= dropout < 1.0:
            raise ValueError(f"{self.name}: num_classes must be >= 1 and dropout p in [0, 1), got {num_classes}, {dropout}")
        net = get_model(self.model, weights=None, num_classes=num_classes)
        attr, head = _head(net)
        layers = [head] if isinstance(head, nn.Linear) else list(head.children())
        odd = [type(m).__name__ for m in layers
               if not isinstance(m, (nn.Linear, nn.Dropout)) and type(m).__name__ not in ROW_LAYERS]
        if odd or not isinstance(layers[-1], nn.Linear):
            raise ValueError(f"{self.name}: its head '{attr}' holds {odd or [type(layers[-1]).__name__]}; MC dropout "
                             "here needs a head of Linear, Dropout and activation layers ending in a Linear")
        if not any(isinstance(m, nn.Dropout) for m in layers):
            layers = [*layers[:-1], nn.Dropout(dropout), layers[-1]]  # the declared insertion
        for m in layers:
            if isinstance(m, nn.Dropout):
                m.p = float(dropout)

        def trunk(x):
            seen = {}

            def stop(_module, args):
                seen["x"] = args[0]
                raise _HeadReached

            hook = head.register_forward_pre_hook(stop)
            try:
                net(x)
            except _HeadReached:
                pass
            finally:
                hook.remove()
            return torch.flatten(seen["x"], 1)

        # The site travels with the network (pipeline.scoring.mc_dropout reads trunk / head_layers);
        # plain attributes, so the state dict keeps torchvision's keys.
        object.__setattr__(net, "trunk", trunk)
        object.__setattr__(net, "head_layers", lambda: list(layers))
        return net

    @property
    def mc_dropout_site(self):
        return ("the Dropout layers of the head (a Dropout inserted before the final Linear when it has none)")

    def last_linear_key(self):
        from torch import nn

        net = self.build(1, 0.0)
        attr, head = _head(net)
        if isinstance(head, nn.Linear):
            return f"{attr}.weight"
        return f"{attr}.{[k for k, m in head.named_children() if isinstance(m, nn.Linear)][-1]}.weight"


def _factory(model: str) -> TorchvisionClassifier:
    import torchvision
    import torchvision.models as M
    from torchvision.models import list_models

    known = list_models(module=M)  # classification networks only
    if model not in known:
        raise UnknownClassifier(f"'torchvision:{model}': torchvision {torchvision.__version__} has no classification "
                                f"model {model!r} (e.g. {', '.join(known[:6])}, ...)")
    return TorchvisionClassifier(model)


register_family(FAMILY, _factory)
