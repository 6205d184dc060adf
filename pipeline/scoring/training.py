"""Training the dropout AlexNet on the source domain: the learning-rate schedule, augmentation,
the loop, prediction and the confusion matrix. MC-dropout scoring is in ``pipeline/scoring/mc_dropout.py``."""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from pipeline.infra import seeds
from pipeline.infra.config.learning import early_epochs_run
from pipeline.infra.threads import pace
from pipeline.infra.memory import reuse_freed_memory
from pipeline.infra.progress import bar as progress_bar


def lr_at(step: int, total: int, base: float, warmup: int) -> float:
    """Linear warmup, then cosine decay to zero (AlexNet has no batch norm: warmup keeps Adam calm)."""
    if warmup > 0 and step < warmup:
        return base * (step + 1) / warmup
    t = (step - warmup) / max(1, total - warmup)
    return base * 0.5 * (1 + math.cos(math.pi * min(1.0, t)))


def train_classifier(model: nn.Module, images: np.ndarray, labels: np.ndarray, *, epochs: int,
                     batch_size: int, lr: float, weight_decay: float, warmup_steps: int, seed: int,
                     mean, std, device: str = "cpu", precision: str = "auto", progress: bool = True,
                     log: Callable[[str], None] | None = None, split: dict | None = None,
                     early_epochs: int = 0, early_size: int | None = None, early_mode: str = "shrink",
                     early_forward: Callable | None = None) -> list[dict]:
    """Adam + warmup/cosine on uint8 images, ``augment``ed per batch. Returns per-epoch history.

    ``precision`` "bf16" = autocast mixed precision (fp32 master weights), several times faster on
    CPUs with native bf16 and slower where oneDNN emulates it; "auto" picks it only where the
    hardware has it (``resolve_precision``). ``split``, if given, receives
    the wall seconds spent in each part of the loop (augment, forward, backward, optimizer).
    The first ``early_epochs`` epochs see ``early_size`` inputs, cheaper steps: ``early_mode``
    "crop" cuts one random ``early_size`` square from each batch (``crop``: the texture periods keep
    the scale they have at full size), "shrink" resizes the batch (``shrink``: it blurs the fine
    periods). ``early_forward(model, x)``, where given, replaces ``model(x)`` in those epochs (the
    AlexNet entry's compact head: ``pipeline.scoring.alexnet.compact_forward``). The last epoch always
    runs at full size with the model's own forward, and an ``early_size`` not below the images' side
    changes nothing.
    """

    torch.manual_seed(seed)
    gen = seeds.stream(seed, 7)  # the minibatch order's stream
    use_bf16 = resolve_precision(precision, device) == "bf16"
    # channels_last: oneDNN's fast convolution layout on CPU (and tensor-core friendly on GPU).
    model.to(device).to(memory_format=torch.channels_last).train()
    kw = {"fused": True} if device in ("cpu", "cuda") else {}
    opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay, **kw)
    n = len(images)
    if early_mode not in ("crop", "shrink"):
        raise ValueError(f"early_mode must be crop or shrink, got {early_mode!r}")
    early_epochs = early_epochs_run(epochs, early_epochs, early_size, images.shape[1])
    steps_per_epoch = math.ceil(n / batch_size)
    total = epochs * steps_per_epoch
    step = 0
    history = []
    parts = dict.fromkeys(("augment_s", "forward_s", "backward_s", "optimizer_s"), 0.0)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    clock = _PartClock(parts, sync)
    bar = progress_bar(total=total, desc="train classifier", unit="step", enabled=progress)
    with reuse_freed_memory():
        for ep in range(epochs):
            order = gen.permutation(n)
            loss_sum, correct, seen = 0.0, 0, 0
            for b in range(steps_per_epoch):
                pace()   # the torch threads the free cores allow now (where the stage follows them)
                clock.start()
                idx = np.sort(order[b * batch_size:(b + 1) * batch_size])
                x = augment(images[idx], gen, mean, std).to(device)
                early = ep < early_epochs
                if early:
                    x = crop(x, early_size, gen) if early_mode == "crop" else shrink(x, early_size)
                y = torch.from_numpy(labels[idx]).to(device)
                clock.lap("augment_s")
                with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=use_bf16):
                    out = early_forward(model, x) if early and early_forward else model(x)
                loss = F.cross_entropy(out.float(), y)
                clock.lap("forward_s")
                opt.zero_grad(set_to_none=True)
                loss.backward()
                clock.lap("backward_s")
                for g in opt.param_groups:
                    g["lr"] = lr_at(step, total, lr, warmup_steps)
                opt.step()
                clock.lap("optimizer_s")
                step += 1
                loss_sum += float(loss.detach()) * len(idx)
                correct += int((out.argmax(1) == y).sum())
                seen += len(idx)
                bar.update(1)
                bar.set_postfix_str(f"loss={loss_sum / seen:.3f}, acc={correct / seen:.3f}")
            history.append({"epoch": ep + 1, "loss": loss_sum / seen, "train_accuracy": correct / seen})
            if log:
                log(f"epoch {ep + 1}/{epochs}: loss {loss_sum / seen:.4f}, train top-1 {correct / seen:.4f}")
    bar.close()
    model.eval().to(memory_format=torch.contiguous_format)
    if split is not None:
        split.update({k: round(v, 2) for k, v in parts.items()})
    return history


def shrink(x: torch.Tensor, size: int) -> torch.Tensor:
    """A batch (N, 3, H, W) resized to ``size`` x ``size`` (antialiased bilinear, as an area
    filter would when shrinking), kept channels_last. Unchanged when it already has that size."""
    if x.shape[-2:] == (size, size):
        return x
    y = F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return y.contiguous(memory_format=torch.channels_last)


def crop(x: torch.Tensor, size: int, gen: np.random.Generator) -> torch.Tensor:
    """One random ``size`` x ``size`` square of a batch (N, 3, H, W), the same place in every image
    (one draw of ``gen`` per batch), kept channels_last. Unchanged when it already has that size."""
    h, w = x.shape[-2:]
    if (h, w) == (size, size):
        return x
    if size > min(h, w):
        raise ValueError(f"crop side {size} exceeds the batch's {h}x{w} images")
    top, left = (int(v) for v in gen.integers(0, [h - size + 1, w - size + 1]))
    return x[:, :, top:top + size, left:left + size].contiguous(memory_format=torch.channels_last)


class _PartClock:
    """Adds the wall time since the previous lap to ``parts[name]`` (after a device sync)."""

    def __init__(self, parts: dict, sync):
        self.parts, self.sync, self.t = parts, sync, 0.0

    def start(self) -> None:
        self.t = time.perf_counter()

    def lap(self, name: str) -> None:
        self.sync()
        now = time.perf_counter()
        self.parts[name] += now - self.t
        self.t = now


def augment(xb: np.ndarray, gen: np.random.Generator, mean, std) -> torch.Tensor:
    """Cheap batch augmentation on top of the rendered variety: the 8 flips/quarter turns (texture
    families have no preferred orientation) and a per-image contrast/brightness jitter.

    Returns float32 (N, 3, H, W) in channels_last memory (the layout training runs in): the images
    are turned in groups of equal (turn, flip), not one by one.
    """
    n = len(xb)
    k = gen.integers(0, 4, n)
    flip = gen.random(n) < 0.5
    c = gen.uniform(0.8, 1.2, (n, 1, 1, 1))
    b = gen.uniform(-0.2, 0.2, (n, 1, 1, 1))
    xb = np.asarray(xb)
    if xb.ndim != 4 or xb.shape[-1] != 3 or xb.dtype != np.uint8:
        raise ValueError(f"expected uint8 images (N, H, W, 3), got {xb.dtype} {xb.shape}")
    out = np.empty_like(xb)
    for kk in range(4):
        for ff in (False, True):
            sel = np.flatnonzero((k == kk) & (flip == ff))
            if len(sel):
                t = np.rot90(xb[sel], kk, axes=(1, 2))
                out[sel] = t[:, :, ::-1] if ff else t
    # crops.to_tensor's float32 arithmetic, then c and b, op by op as before the batching (the
    # same roundings, so a seed's weights are byte-identical to the image-by-image version's), in
    # numpy on the HWC array: about 4x faster than torch's broadcasts, and its NCHW view is
    # channels_last.
    x = out.astype(np.float32)
    x /= np.float32(255.0)
    x -= np.asarray(mean, np.float32)
    x /= np.asarray(std, np.float32)
    x *= c.astype(np.float32)
    x += b.astype(np.float32)
    return torch.from_numpy(x).permute(0, 3, 1, 2)


# CPU flags of native bf16 arithmetic. oneDNN also runs bf16 autocast on plain AVX-512 CPUs by
# emulating it, and there a training step costs about 2.4x fp32's CPU time (docs/benchmarks.md).
NATIVE_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


def resolve_precision(precision: str, device: str, flags: set[str] | None = None) -> str:
    """``auto``: bf16 autocast on a GPU that supports it or a CPU with native bf16 instructions
    (``NATIVE_BF16_FLAGS``; ``flags`` defaults to this machine's), else fp32."""
    if precision not in ("auto", "fp32", "bf16"):
        raise ValueError(f"precision must be auto, fp32 or bf16, got {precision!r}")
    if precision != "auto":
        return precision
    if device == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    if flags is None:
        from pipeline.infra.fingerprint import cpu_flags  # heavy: torch

        flags = cpu_flags()
    if not any(f in flags for f in NATIVE_BF16_FLAGS):
        return "fp32"
    try:
        return "bf16" if torch.ops.mkldnn._is_mkldnn_bf16_supported() else "fp32"
    except (AttributeError, RuntimeError):  # pragma: no cover - builds without oneDNN
        return "fp32"


@torch.inference_mode()
def predict(model: nn.Module, images: np.ndarray, *, mean, std, batch_size: int = 128,
            device: str = "cpu", progress: bool = False) -> np.ndarray:
    """Eval-mode logits (n, D) for uint8 images."""
    from pipeline.scoring.crops import to_tensor  # heavy: cv2

    model.eval().to(device)
    outs = []
    for s in progress_bar(range(0, len(images), batch_size), desc="validate", unit="batch", enabled=progress, leave=False):
        pace()
        outs.append(model(to_tensor(images[s:s + batch_size], mean, std).to(device)).float().cpu())
    return torch.cat(outs).numpy()


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray, k: int) -> np.ndarray:
    cm = np.zeros((k, k), np.int64)
    np.add.at(cm, (y_true, y_pred), 1)
    return cm
