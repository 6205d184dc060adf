"""Dropout AlexNet: building it, the weights policy and training on the source domain.

Weights never travel as pickles: our checkpoints are ``.npz`` (plain arrays, read with
``allow_pickle=False``); torch checkpoint files are read with ``torch.load(weights_only=True)``,
which refuses to run code. Nothing is downloaded. MC-dropout scoring is in ``pipeline/scoring/mc_dropout.py``.
"""
from __future__ import annotations

import io
import json
import math
import time
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from pipeline.infra.outputs import name as out_name
from pipeline.infra.cache import NpzFileError, atomic_path, hash_json, load_npz, sha256_file

IMAGENET_FILE = "alexnet-owt-7be5be79.pth"   # torchvision AlexNet_Weights.IMAGENET1K_V1
ARCHITECTURE = "torchvision.models.alexnet"
CARD = out_name("classifier", "card")
WEIGHTS_NPZ = out_name("classifier", "weights")


class WeightsError(ValueError):
    """A weights file is unreadable or does not fit the architecture; names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


class WeightsNotFoundError(FileNotFoundError):
    """The requested weights file is not on disk (and will not be downloaded)."""


# -- architecture ------------------------------------------------------------------------------
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


def imagenet_dir() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints"


def imagenet_checkpoint() -> Path:
    """The local IMAGENET1K_V1 file, or a clear error: viewfuse never downloads weights."""
    folder = imagenet_dir()
    path = folder / IMAGENET_FILE
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


# -- state dict files (no pickles) ---------------------------------------------------------------
def load_state_dict_file(path: str | Path) -> dict[str, torch.Tensor]:
    """A state dict from ``.npz`` (ours) or a torch file read with the safe loader."""
    path = Path(path)
    if not path.is_file():
        raise WeightsNotFoundError(f"{path}: weights file not found")
    if path.suffix == ".npz":
        try:
            state = {k: torch.from_numpy(np.array(v)) for k, v in load_npz(path).items()}
        except NpzFileError as e:
            raise WeightsError(path, f"not a readable .npz state dict ({e.problem})") from None
    else:
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # the safe loader raises UnpicklingError/RuntimeError on anything odd
            raise WeightsError(path, f"not a tensor-only torch state dict (loaded with weights_only=True): "
                                     f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}") from None
        if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
            obj = obj["state_dict"]
        if not isinstance(obj, dict):
            raise WeightsError(path, f"expected a dict of tensors, got {type(obj).__name__}")
        state = obj
    out = {}
    for k, v in state.items():
        if not isinstance(v, torch.Tensor):
            raise WeightsError(path, f"entry {k!r} is not a tensor ({type(v).__name__})")
        out[k[7:] if k.startswith("module.") else k] = v  # DataParallel prefix
    if not out:
        raise WeightsError(path, "empty state dict")
    return out


def num_classes_of(state: dict[str, torch.Tensor], path: str | Path) -> int:
    w = state.get("classifier.6.weight")
    if w is None or w.ndim != 2:
        raise WeightsError(path, "no 'classifier.6.weight' matrix: not an AlexNet state dict")
    return int(w.shape[0])


def load_into(model: nn.Module, state: dict[str, torch.Tensor], path: str | Path) -> nn.Module:
    """Strict load with an error that names the file and the first mismatches."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    bad = [k for k in own if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or bad:
        parts = []
        if missing:
            parts.append(f"missing keys {missing[:4]}")
        if unexpected:
            parts.append(f"unexpected keys {unexpected[:4]}")
        if bad:
            k = bad[0]
            parts.append(f"shape mismatch for {k!r}: file {tuple(state[k].shape)} vs AlexNet {tuple(own[k].shape)}")
        raise WeightsError(path, "does not fit torchvision's AlexNet: " + "; ".join(parts))
    model.load_state_dict({k: v.to(own[k].dtype) for k, v in state.items()}, strict=True)
    return model


def save_state_dict_npz(model_or_state, path: str | Path) -> str:
    """Write a state dict as ``.npz`` atomically and reproducibly; returns the file's sha256.

    Each array goes in as ``<name>.npy`` with a fixed zip timestamp, so identical weights give an
    identical file (and hash). ``np.load(path, allow_pickle=False)`` reads it back.
    """
    state = model_or_state.state_dict() if isinstance(model_or_state, nn.Module) else model_or_state
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for k in sorted(state):
                arr = np.ascontiguousarray(state[k].detach().cpu().numpy())
                buf = io.BytesIO()
                np.lib.format.write_array(buf, arr, allow_pickle=False)
                info = zipfile.ZipInfo(k + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
                zf.writestr(info, buf.getvalue())
    return sha256_file(path)


# -- card: the identity of a scorer --------------------------------------------------------------
def card_hash(card: dict) -> str:
    """Hash of everything that changes a score (not timings or accuracy bookkeeping)."""
    keys = ("architecture", "weights_sha256", "num_classes", "output_names", "dropout", "input_size", "mean", "std")
    return hash_json({k: card.get(k) for k in keys})


def read_card(folder: str | Path) -> dict:
    p = Path(folder) / CARD
    if not p.is_file():
        raise FileNotFoundError(f"{p}: classifier card not found (run `viewfuse classifier` first)")
    try:
        card = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: not valid JSON ({e})") from None
    for k in ("weights_file", "weights_sha256", "num_classes", "output_names", "dropout", "hash"):
        if k not in card:
            raise ValueError(f"{p}: classifier card lacks key {k!r}")
    return card


def weights_path(folder: str | Path, card: dict) -> Path:
    p = Path(card["weights_file"])
    return p if p.is_absolute() else Path(folder) / p


def load_classifier(folder: str | Path, device: str = "cpu", verify: bool = True) -> tuple[nn.Module, dict]:
    """Model (eval mode, on ``device``) and card from a classifier artifact folder."""
    card = read_card(folder)
    wp = weights_path(folder, card)
    if not wp.is_file():
        raise WeightsNotFoundError(f"{wp}: weights file named by {Path(folder) / CARD} is missing")
    if verify and sha256_file(wp) != card["weights_sha256"]:
        raise WeightsError(wp, f"sha256 differs from the one recorded in {Path(folder) / CARD}: the file "
                               f"changed since the classifier stage ran (rerun it)")
    model = build_alexnet(int(card["num_classes"]), float(card["dropout"]))
    load_into(model, load_state_dict_file(wp), wp)
    return model.eval().to(device), card


# -- training on the source domain -----------------------------------------------------------------
def lr_at(step: int, total: int, base: float, warmup: int) -> float:
    """Linear warmup, then cosine decay to zero (AlexNet has no batch norm: warmup keeps Adam calm)."""
    if warmup > 0 and step < warmup:
        return base * (step + 1) / warmup
    t = (step - warmup) / max(1, total - warmup)
    return base * 0.5 * (1 + math.cos(math.pi * min(1.0, t)))


def train_classifier(model: nn.Module, images: np.ndarray, labels: np.ndarray, *, epochs: int,
                     batch_size: int, lr: float, weight_decay: float, warmup_steps: int, seed: int,
                     mean, std, device: str = "cpu", precision: str = "auto", progress: bool = True,
                     log: Callable[[str], None] | None = None, split: dict | None = None) -> list[dict]:
    """Adam + warmup/cosine on uint8 images, ``augment``ed per batch. Returns per-epoch history.

    ``precision`` "bf16" = autocast mixed precision (fp32 master weights), several times faster on
    CPUs with native bf16; "auto" picks it where the hardware has it. ``split``, if given, receives
    the wall seconds spent in each part of the loop (augment, forward, backward, optimizer).
    """
    from pipeline.infra.memory import reuse_freed_memory
    from pipeline.infra.progress import bar as progress_bar

    torch.manual_seed(seed)
    gen = np.random.default_rng([seed, 7])
    use_bf16 = resolve_precision(precision, device) == "bf16"
    # channels_last: oneDNN's fast convolution layout on CPU (and tensor-core friendly on GPU).
    model.to(device).to(memory_format=torch.channels_last).train()
    kw = {"fused": True} if device in ("cpu", "cuda") else {}
    opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay, **kw)
    n = len(images)
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
                clock.start()
                idx = np.sort(order[b * batch_size:(b + 1) * batch_size])
                x = augment(images[idx], gen, mean, std).to(device)
                y = torch.from_numpy(labels[idx]).to(device)
                clock.lap("augment_s")
                with torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=use_bf16):
                    out = model(x)
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


def resolve_precision(precision: str, device: str) -> str:
    if precision not in ("auto", "fp32", "bf16"):
        raise ValueError(f"precision must be auto, fp32 or bf16, got {precision!r}")
    if precision != "auto":
        return precision
    if device == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    try:
        return "bf16" if torch.ops.mkldnn._is_mkldnn_bf16_supported() else "fp32"
    except (AttributeError, RuntimeError):  # pragma: no cover - builds without oneDNN
        return "fp32"


@torch.inference_mode()
def predict(model: nn.Module, images: np.ndarray, *, mean, std, batch_size: int = 128,
            device: str = "cpu", progress: bool = False) -> np.ndarray:
    """Eval-mode logits (n, D) for uint8 images."""
    from pipeline.scoring.crops import to_tensor
    from pipeline.infra.progress import bar as progress_bar

    model.eval().to(device)
    outs = []
    for s in progress_bar(range(0, len(images), batch_size), desc="validate", unit="batch", enabled=progress, leave=False):
        outs.append(model(to_tensor(images[s:s + batch_size], mean, std).to(device)).float().cpu())
    return torch.cat(outs).numpy()


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray, k: int) -> np.ndarray:
    cm = np.zeros((k, k), np.int64)
    np.add.at(cm, (y_true, y_pred), 1)
    return cm


# -- what can make weights differ across machines ------------------------------------------------
# CPU features that select different oneDNN/BLAS kernels (and so different rounding) for the same
# training code: bf16/AMX paths exist only on some CPUs; AVX-512 vs AVX2 changes the reduction order.
KERNEL_FLAGS = ("avx2", "fma", "avx512f", "avx512bw", "avx512_vnni", "avx512_bf16", "avx512_fp16",
                "amx_tile", "amx_bf16", "amx_int8")
CROSS_MACHINE_NOTE = (
    "Same machine, same seed, same thread count: byte-identical weights. On another machine the "
    "weights (and so every score downstream) can differ in the last bits and then drift during "
    "training, because oneDNN picks kernels by CPU features (the cpu_flags here: bf16/AMX "
    "autocast exists only where avx512_bf16/amx_bf16 do, AVX-512 vs AVX2 changes summation "
    "order) and by thread count, and library versions change kernels too; the seed study "
    "(viewfuse study) measures how much a verdict depends on one training run.")


def machine_fingerprint() -> dict:
    """CPU model and kernel-relevant flags, thread count and library versions (for card.json)."""
    import platform

    model, flags = platform.processor() or "", set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name") and not model.strip():
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:  # not Linux: flags unknown
        pass
    versions = {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}
    for mod in ("torchvision", "cv2"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:  # pragma: no cover
            versions[mod] = None
    return {"cpu_model": model, "cpu_flags": [f for f in KERNEL_FLAGS if f in flags],
            "machine": platform.machine(), "torch_threads": torch.get_num_threads(),
            "onednn": bool(torch.backends.mkldnn.is_available()), "versions": versions,
            "cross_machine": CROSS_MACHINE_NOTE}
