"""MC-dropout scoring (paper §4.3) with the networks of ``pipeline.scoring.classifiers``.

AlexNet is ``features -> avgpool -> flatten -> classifier`` with ``classifier = (Dropout,
Linear, ReLU, Dropout, Linear, ReLU, Linear)``; EfficientNet-Lite0 is its trunk (stem, blocks, head
convolution, pooling) then ``(Dropout, Linear)``. The dropout layers are all in the head, so ``N_s``
stochastic passes share one trunk output: the trunk runs once per crop, then the head on
``(B * N_s)`` rows with independent Bernoulli(1 - p) masks scaled by ``1/(1 - p)`` (exactly what
``nn.Dropout`` does in train mode). Masks come from a per-crop seeded generator, so a crop's
samples depend only on (seed, crop key), not on batch size, order or device.

A network with MC drop-connect in its trunk (EfficientNet-Lite0 with ``drop_connect`` > 0) cannot
share the trunk: each sample then runs the trunk with its own per-block keep factors (drawn from a
second stream of the crop's seed, so the head masks are the same as without drop-connect), in
groups of ``TRUNK_ROWS`` images.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from pipeline.infra.seeds import stream
from pipeline.infra.seeds import crop_seed  # noqa: F401 - public here (the features stage, viewfuse.scoring)


def mc_site(model: nn.Module) -> tuple[Callable[[torch.Tensor], torch.Tensor], list[nn.Module]]:
    """(trunk: input -> flat features, head layers in order): the site a network declares with
    ``trunk`` and ``head_layers``, else torchvision's ``features -> avgpool -> flatten | classifier``."""
    if hasattr(model, "trunk") and hasattr(model, "head_layers"):
        return model.trunk, list(model.head_layers())
    for attr in ("features", "avgpool", "classifier"):
        if not hasattr(model, attr):
            raise TypeError(f"model has no '{attr}' and declares no trunk/head_layers: no MC-dropout site")

    def trunk(x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(model.avgpool(model.features(x)), 1)

    return trunk, list(model.classifier)


class OneDNNLinear(nn.Module):
    """``nn.Linear`` through oneDNN's fp32 inner product with the weight packed once.

    Same weights and arithmetic precision as the layer it wraps; on this CPU it runs the big head
    matmuls about twice as fast as the default BLAS path (the head dominates MC-dropout scoring).
    """

    def __init__(self, linear: nn.Linear):
        super().__init__()
        self.in_features, self.out_features = linear.in_features, linear.out_features
        w = linear.weight.detach().float().contiguous()
        b = linear.bias.detach().float() if linear.bias is not None else torch.zeros(w.shape[0])
        self.weight = w.to_mkldnn()
        self.bias = b.contiguous().to_mkldnn()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch._C._nn.mkldnn_linear(x.contiguous().to_mkldnn(), self.weight, self.bias).to_dense()


def onednn_available() -> bool:
    try:
        if not torch.backends.mkldnn.is_available():
            return False
        lin = nn.Linear(4, 3)
        x = torch.randn(2, 4)
        return bool(torch.allclose(OneDNNLinear(lin)(x), lin(x), atol=1e-5))
    except (AttributeError, RuntimeError):  # pragma: no cover - builds without oneDNN
        return False


def fast_head(classifier: nn.Module, device: str, onednn: bool = True) -> list[nn.Module]:
    """The head's layers, Linear ones swapped for oneDNN on CPU when available (same weights)."""
    use = onednn and device == "cpu" and onednn_available()
    return [OneDNNLinear(m) if use and isinstance(m, nn.Linear) else m for m in classifier]


# (crop, sample) rows per head pass: about 150 kB each (masks, masked activations), so a pass holds
# at most ~0.3 GB however large N_s grows; the default batch (64 crops x 10 samples) is one pass.
HEAD_ROWS = 2048
# images per trunk call when drop-connect makes every sample run the trunk (224 px EfficientNet-Lite0
# activations are ~5 MB an image at their largest)
TRUNK_ROWS = 32
# images per trunk call when scoring: a batch of 64 at 160 px makes EfficientNet-Lite0 activations of
# ~150 MB, which glibc maps and unmaps afresh for every layer (page faults: sys time about equal to
# the trunk's own user time on this machine); 16 keeps them near the heap's mmap threshold and gave
# bit-identical features (tests/pipeline/scoring/test_scoring_route.py bounds them by 1e-6)
TRUNK_CHUNK = 16


class MCDropoutScorer:
    """Trunk once per crop, then the head in eval mode and/or ``N_s`` times with dropout masks.

    ``p`` is read from the model's Dropout layers. ``masks`` are lists (one per Dropout layer, in
    order) of float tensors ``(B, N_s, F_k)`` with entries 0 or ``1/(1-p)``. ``onednn``: run the
    head's matmuls through oneDNN on CPU (see ``OneDNNLinear``). ``channels_last``: the trunk's
    convolutions in NHWC, oneDNN's fast layout (AlexNet's trunk at 112 px: 2.4 against 4.0 CPU ms a
    crop here, ``tests/bench/bench_features.py``); the scores move by rounding only, how much
    depends on the network (the registry's ``channels_last_scoring`` says where it is within 1e-6).
    """

    def __init__(self, model: nn.Module, device: str = "cpu", onednn: bool = True, channels_last: bool = False):
        self._trunk, head = mc_site(model)
        self.format = torch.channels_last if channels_last else torch.contiguous_format
        self.model = model.eval().to(device).to(memory_format=self.format)
        self.device = device
        self.head = fast_head(head, device, onednn)
        self.dropout_dims: list[int] = []
        self.p: list[float] = []
        for i, m in enumerate(self.head):
            if isinstance(m, nn.Dropout):
                nxt = next((l for l in self.head[i + 1:] if hasattr(l, "in_features")), None)
                if nxt is None:
                    raise TypeError("a Dropout layer without a following Linear layer in the head")
                self.dropout_dims.append(nxt.in_features)
                self.p.append(float(m.p))
        # MC drop-connect in the trunk: the rates of the blocks it samples (none for AlexNet)
        self.block_rates = [r for _, r in getattr(model, "drop_blocks", [])]

    # The parts, separately (the benchmark times them one by one).
    def _input(self, x: torch.Tensor) -> torch.Tensor:
        return x.to(self.device).contiguous(memory_format=self.format)

    @torch.inference_mode()
    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[0]
        if n < 2 * TRUNK_CHUNK:
            return self._trunk(self._input(x))
        # the last chunk takes the remainder: no call gets fewer than TRUNK_CHUNK images (oneDNN
        # takes another convolution path below ~10 images, which moves features by ~5e-6)
        cuts = [a for a in range(0, n, TRUNK_CHUNK) if n - a >= TRUNK_CHUNK] + [n]
        return torch.cat([self._trunk(self._input(x[a:b])) for a, b in zip(cuts, cuts[1:])])

    @torch.inference_mode()
    def head_eval(self, f: torch.Tensor) -> torch.Tensor:
        for m in self.head:
            if not isinstance(m, nn.Dropout):
                f = m(f)
        return f

    def draw_masks(self, seeds: Sequence[int], n_samples: int) -> list[torch.Tensor]:
        """Bernoulli(1-p)/(1-p) masks, one seeded generator per crop (device-independent).

        Each crop draws ``n_samples x sum(F_k)`` float32 uniforms from its own PCG64 stream and
        keeps a unit where the uniform is below 1 - p: the same law as ``nn.Dropout``, several
        times cheaper than torch's per-generator ``bernoulli_`` on CPU.
        """
        B = len(seeds)
        dims = self.dropout_dims
        total = sum(dims)
        keep = np.concatenate([np.full(d, 1.0 - p, np.float32) for d, p in zip(dims, self.p)])
        bits = np.empty((B, n_samples, total), dtype=bool)
        for b, s in enumerate(seeds):
            u = np.random.default_rng(int(s)).random((n_samples, total), dtype=np.float32)
            np.less(u, keep, out=bits[b])
        masks, start = [], 0
        for d, p in zip(dims, self.p):
            m = torch.from_numpy(bits[:, :, start:start + d]).to(self.device, non_blocking=True).float()
            masks.append(m.mul_(1.0 / (1.0 - p)) if p > 0 else m)
            start += d
        return masks

    def draw_block_keeps(self, seeds: Sequence[int], n_samples: int) -> torch.Tensor:
        """Drop-connect factors (B, N_s, K), 0 or 1/(1-rate) per sampled block, from a second
        stream of each crop's seed (the head masks' stream is left as it is)."""
        keep = np.asarray([1.0 - r for r in self.block_rates], np.float32)
        out = np.empty((len(seeds), n_samples, len(keep)), np.float32)
        for b, s in enumerate(seeds):
            u = stream(int(s), 1).random((n_samples, len(keep)), dtype=np.float32)  # the block masks' stream
            out[b] = (u < keep) / keep
        return torch.from_numpy(out).to(self.device)

    @torch.inference_mode()
    def trunk_samples(self, x: torch.Tensor, keeps: torch.Tensor) -> torch.Tensor:
        """Features (B, N_s, F): the trunk once per (crop, sample) with its drop-connect factors."""
        B, n, K = keeps.shape
        step = max(1, TRUNK_ROWS // n)  # crops per trunk call: their N_s copies, ~TRUNK_ROWS images
        f = [self._trunk(self._input(x[a:a + step].repeat_interleave(n, dim=0)), keeps[a:a + step].reshape(-1, K))
             for a in range(0, B, step)]
        return torch.cat(f).reshape(B, n, -1)

    @torch.inference_mode()
    def head_samples(self, f: torch.Tensor, masks: Sequence[torch.Tensor]) -> torch.Tensor:
        """Logits (B, N_s, D): the head on B*N_s rows, one mask row each, one matmul chain. ``f``:
        trunk features (B, F), shared by the samples, or (B, N_s, F), one per sample."""
        B = f.shape[0]
        n = masks[0].shape[1]
        h = f.unsqueeze(1) if f.dim() == 2 else f  # (B, 1, F): broadcast over samples at the first mask
        k = 0
        for m in self.head:
            if isinstance(m, nn.Dropout):
                mk = masks[k]
                h = (h.reshape(B, -1, mk.shape[2]) * mk).reshape(B * n, mk.shape[2])
                k += 1
            else:
                h = m(h if h.dim() == 2 else h.reshape(B, -1))
        return h.reshape(B, n, -1)

    @torch.inference_mode()
    def score(self, x: torch.Tensor, seeds: Sequence[int] | None = None, n_samples: int = 0
              ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Softmax scores: deterministic (B, D) and, if ``n_samples``, MC samples (B, N_s, D)."""
        f = self.trunk(x)
        det = F.softmax(self.head_eval(f), dim=-1)
        if not n_samples:
            return det, None
        if seeds is None or len(seeds) != f.shape[0]:
            raise ValueError("score: one mask seed per crop is needed for MC samples")
        # Crops in groups of HEAD_ROWS // N_s: each crop's masks come from its own generator and its
        # rows are its own, so the grouping changes memory only.
        per = max(1, HEAD_ROWS // int(n_samples))

        def features(a: int) -> torch.Tensor:
            if not self.block_rates:
                return f[a:a + per]  # shared by the samples
            # drop-connect: the trunk once per sample
            return self.trunk_samples(x[a:a + per], self.draw_block_keeps(seeds[a:a + per], n_samples))

        parts = [F.softmax(self.head_samples(features(a), self.draw_masks(seeds[a:a + per], n_samples)), dim=-1)
                 for a in range(0, f.shape[0], per)]
        return det, parts[0] if len(parts) == 1 else torch.cat(parts)
