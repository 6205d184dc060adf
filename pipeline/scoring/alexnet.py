"""The dropout AlexNet: its architecture (torchvision's, with the dropout rate a setting), the
initialisation for training, and where the ImageNet checkpoint and class names are found (nothing is
downloaded)."""
from __future__ import annotations

import math
import os
from pathlib import Path

import torch
from torch import nn
from pipeline.scoring.weight_files import WeightsNotFoundError, regular_weights_file


IMAGENET_FILE = "alexnet-owt-7be5be79.pth"   # torchvision AlexNet_Weights.IMAGENET1K_V1
ARCHITECTURE = "torchvision.models.alexnet"


def build_alexnet(num_classes: int, dropout: float = 0.5) -> nn.Module:
    """torchvision's AlexNet (random init), ``num_classes`` outputs, head dropout ``p``."""
    from torchvision.models import alexnet

    if num_classes < 1:
        raise ValueError(f"num_classes must be >= 1, got {num_classes}")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout p must be in [0, 1), got {dropout}")
    return alexnet(weights=None, num_classes=num_classes, dropout=dropout)


def init_for_training(model: nn.Module, seed: int) -> nn.Module:
    """He (fan-in, ReLU) init: torch's default init starts AlexNet (no batch norm) with vanishing
    activations, and from-scratch training then idles for an epoch at chance level."""
    g = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)):
                fan_in = m.weight[0].numel()
                m.weight.normal_(0.0, math.sqrt(2.0 / fan_in), generator=g)
                m.bias.zero_()
        last = model.classifier[-1]
        last.weight.mul_(0.1)  # start near uniform class scores
    return model


def compact_forward(model: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """AlexNet's logits with the head's first Dropout off, its first Linear layer computed once per
    distinct trunk output. AdaptiveAvgPool2d((6, 6)) only repeats a trunk map whose sides divide 6
    (1x1 at 80 px inputs: 36 copies; 3x3 at 112 px: 4), so the layer equals a Linear layer on the
    unrepeated map whose weights are the sums of the copies' columns: exactly the full head without
    that Dropout (autograd hands every copy the same gradient), at a 36th (4th) of its multiply-adds.
    Other map sizes take the full layers, the first Dropout still off. Used by the early epochs of
    training (``classifier.training.early_head``); the MC-dropout network keeps both Dropouts."""
    head = model.classifier
    fc1 = head[1]
    f = model.features(x)
    c, h, w = f.shape[1:]
    out_h, out_w = model.avgpool.output_size
    if out_h % h or out_w % w or c * out_h * out_w != fc1.in_features:
        z = fc1(torch.flatten(model.avgpool(f), 1))
    else:
        # flatten order of (C, 6, 6) is c*36 + row*6 + col; row = i*(6/h) + r repeats map row i
        weight = fc1.weight.view(fc1.out_features, c, h, out_h // h, w, out_w // w).sum((3, 5))
        z = nn.functional.linear(torch.flatten(f, 1), weight.reshape(fc1.out_features, -1), fc1.bias)
    return head[3:](head[2](z))


def imagenet_dir() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints"


def imagenet_checkpoint() -> Path:
    """The local IMAGENET1K_V1 file, or a clear error: viewfuse never downloads weights."""
    folder = imagenet_dir()
    path = folder / IMAGENET_FILE
    if os.path.lexists(path):  # there, but perhaps a FIFO or a device: named as what it is
        return regular_weights_file(path, "ImageNet weights file")
    if not path.is_file():
        raise WeightsNotFoundError(
            f"classifier.weights = 'imagenet' needs torchvision's AlexNet IMAGENET1K_V1 file "
            f"'{IMAGENET_FILE}' in '{folder}' (torch.hub.get_dir()/checkpoints; set TORCH_HOME to "
            f"move it), and it is not there. Nothing is downloaded at run time: copy the file there "
            f"from a machine with network access, or use classifier.weights = 'synthetic' or 'path'.")
    return path


def imagenet_names(n: int) -> list[str]:
    """ImageNet class names when torchvision ships them (offline metadata), else imagenet_{i}."""
    try:
        from torchvision.models import AlexNet_Weights

        cats = list(AlexNet_Weights.IMAGENET1K_V1.meta["categories"])
        if len(cats) == n:
            return cats
    except Exception:  # pragma: no cover - older torchvision
        pass
    return [f"imagenet_{i}" for i in range(n)]
