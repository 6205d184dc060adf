"""The networks ``classifier.arch`` names, built the same way wherever a classifier is rebuilt (the
classifier stage, a card, a scoring worker), and their split into a trunk (run once per crop) and a
head (the layers from the first Dropout on, resampled for MC dropout).

- ``alexnet``: torchvision's AlexNet, ``features -> avgpool -> flatten`` | ``classifier`` (two
  Dropout layers in the head).
- ``efficientnet_lite0``: ``pipeline.scoring.efficientnet_lite`` | ``Dropout, Linear``.
"""
from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

ARCHES = ("alexnet", "efficientnet_lite0")


def check_arch(arch: str) -> str:
    if arch not in ARCHES:
        raise ValueError(f"unknown classifier architecture {arch!r} (one of {', '.join(ARCHES)})")
    return arch


def build_network(arch: str, num_classes: int, dropout: float, drop_connect: float = 0.0) -> nn.Module:
    """A fresh (untrained) network of ``arch`` with ``num_classes`` outputs, head dropout p and
    (EfficientNet-Lite0 only) MC drop-connect rate in the blocks."""
    if check_arch(arch) == "alexnet":
        from pipeline.scoring.alexnet import build_alexnet

        if drop_connect:
            raise ValueError("drop_connect is an EfficientNet-Lite0 setting; AlexNet has no residual blocks")
        return build_alexnet(num_classes, dropout)
    from pipeline.scoring.efficientnet_lite import EfficientNetLite0

    return EfficientNetLite0(num_classes, dropout, drop_connect)


def architecture_name(arch: str) -> str:
    """The card's ``architecture`` string for ``arch``."""
    if check_arch(arch) == "alexnet":
        from pipeline.scoring.alexnet import ARCHITECTURE
    else:
        from pipeline.scoring.efficientnet_lite import ARCHITECTURE
    return ARCHITECTURE


def display_name(arch: str) -> str:
    return {"alexnet": "torchvision's AlexNet", "efficientnet_lite0": "EfficientNet-Lite0"}[check_arch(arch)]


def num_classes_of(arch: str, state: dict[str, torch.Tensor], path) -> int:
    """Output count read off a state dict of ``arch`` (its last Linear layer's rows)."""
    from pipeline.scoring import weight_files

    if check_arch(arch) == "alexnet":
        return weight_files.num_classes_of(state, path)
    return weight_files.num_classes_of(state, path, key="_fc.weight", what="an EfficientNet-Lite0")


def split(model: nn.Module) -> tuple[Callable[[torch.Tensor], torch.Tensor], list[nn.Module]]:
    """(trunk: input -> flat features, head layers in order) of a network built here."""
    if hasattr(model, "trunk") and hasattr(model, "head_layers"):
        return model.trunk, list(model.head_layers())
    for attr in ("features", "avgpool", "classifier"):
        if not hasattr(model, attr):
            raise TypeError(f"model has no '{attr}': not a torchvision AlexNet nor an EfficientNet-Lite0")

    def trunk(x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(model.avgpool(model.features(x)), 1)

    return trunk, list(model.classifier)
