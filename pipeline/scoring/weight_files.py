"""Weight files without pickles: our checkpoints are ``.npz`` (plain arrays, read with
``allow_pickle=False``); torch checkpoint files are read with ``torch.load(weights_only=True)``,
which refuses to run code. Loading checks the keys and shapes against the model."""
from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

from pipeline.infra.cache import NpzFileError, atomic_path, load_npz, sha256_file
from pipeline.infra.filekind import not_regular


class WeightsError(ValueError):
    """A weights file is unreadable or does not fit the architecture; names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


class WeightsNotFoundError(FileNotFoundError):
    """The requested weights file is not on disk (and will not be downloaded)."""



def regular_weights_file(path: str | Path, what: str = "weights file") -> Path:
    """``path`` if it is a regular file (symlinks followed); WeightsNotFoundError when it is not
    there, WeightsError naming what it is otherwise (a FIFO would block the reader, /dev/zero
    would be read until memory runs out). Only ``stat`` is called, never ``open``."""
    path = Path(path)
    problem = not_regular(path, f"the {what}")
    if problem is not None and problem[0] == "missing":
        raise WeightsNotFoundError(f"{path}: {problem[1]}")
    if problem is not None:
        raise WeightsError(path, problem[1])
    return path


def load_state_dict_file(path: str | Path) -> dict[str, torch.Tensor]:
    """A state dict from ``.npz`` (ours) or a torch file read with the safe loader."""
    path = regular_weights_file(path)
    if path.suffix == ".npz":
        try:
            arrays = load_npz(path)
        except NpzFileError as e:
            raise WeightsError(path, f"not a readable .npz state dict ({e.problem})") from None
        for k, v in arrays.items():
            if np.asarray(v).dtype.kind not in "biuf":  # torch.from_numpy raises TypeError on the rest
                raise WeightsError(path, f"entry {k!r} holds {np.asarray(v).dtype} values, expected numbers")
        state = {k: torch.from_numpy(np.array(v)) for k, v in arrays.items()}
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
    for k, v in out.items():
        if v.is_complex() or not (v.is_floating_point() or v.dtype in _INTEGER):
            raise WeightsError(path, f"entry {k!r} holds {v.dtype} values, expected real numbers")
        if v.is_floating_point():
            bad = int((~torch.isfinite(v)).sum())
            if bad:  # a NaN weight gives NaN scores for every crop
                raise WeightsError(path, f"entry {k!r} {tuple(v.shape)} has {bad} non-finite value(s)")
    return out


_INTEGER = (torch.bool, torch.uint8, torch.int8, torch.int16, torch.int32, torch.int64)


def num_classes_of(state: dict[str, torch.Tensor], path: str | Path, key: str = "classifier.6.weight",
                   what: str = "an AlexNet") -> int:
    """Rows of the last Linear layer's weight ``key``: the output (class) count."""
    w = state.get(key)
    if w is None or w.ndim != 2:
        raise WeightsError(path, f"no '{key}' matrix: not {what} state dict")
    if w.shape[0] < 1:
        raise WeightsError(path, f"'{key}' is {tuple(w.shape)}: no output rows (classes); "
                                 "expected one row per class")
    return int(w.shape[0])


def load_into(model: nn.Module, state: dict[str, torch.Tensor], path: str | Path,
              what: str = "torchvision's AlexNet") -> nn.Module:
    """Strict load with an error that names the file and the first mismatches (``what``: the
    architecture, for the message)."""
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
            parts.append(f"shape mismatch for {k!r}: file {tuple(state[k].shape)} vs the model {tuple(own[k].shape)}")
        raise WeightsError(path, f"does not fit {what}: " + "; ".join(parts))
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
                arr = state[k].detach().cpu().numpy()
                # ascontiguousarray makes a 0-d entry (batch norm's num_batches_tracked) 1-d
                arr = np.ascontiguousarray(arr) if arr.ndim else arr
                buf = io.BytesIO()
                np.lib.format.write_array(buf, arr, allow_pickle=False)
                info = zipfile.ZipInfo(k + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
                zf.writestr(info, buf.getvalue())
    return sha256_file(path)
