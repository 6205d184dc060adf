"""A GP model bank's files: ``index.json`` plus one ``<class>.npz`` per class (arrays only;
loading never unpickles), each class file's sha256 recorded in the index and checked on load."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.infra.cache import NpzFileError, atomic_path, load_npz, sha256_file
from pipeline.method.bank_index import inside, read_index, write_index
from pipeline.method.gp import FORMAT, INDEX, KERNEL_TEXT, VERSION, GPClassModels, ModelFileError
from pipeline.method.gp_instance import InstanceGPClassModels

# The instance term's arrays (pipeline/method/gp_instance.py): in every class file of such a bank, or in none.
INSTANCE_ARRAYS = ("instances", "instance_amplitude", "instance_length_scale")


def save_bank(models, folder: str | Path, extra: dict | None = None) -> Path:
    """Write ``index.json`` + one ``<class>.npz`` per class of ``models`` into ``folder`` (atomic
    per file); ``extra`` keys go into the index beside (never over) the bank's own."""
    self = models
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = _file_names(self.classes)
    digests = {}
    inst = isinstance(self, InstanceGPClassModels)
    for c, cls in enumerate(self.classes):
        extra_arrays = {k: getattr(self, k)[c] for k in INSTANCE_ARRAYS} if inst else {}
        with atomic_path(folder / files[cls]) as tmp:
            with open(tmp, "wb") as fh:  # a file object: np.savez must not append ".npz"
                np.savez(fh, X=self.X[c], Y=self.Y[c], mean=self.mean[c], amplitude=self.amplitude[c],
                         length_scale=self.length_scale[c], noise=self.noise[c],
                         components=np.asarray(self.components, dtype=np.int64), **extra_arrays)
            digests[files[cls]] = sha256_file(tmp)
    index = {
        "format": FORMAT, "version": VERSION,
        "kernel": KERNEL_TEXT + ("; plus b*exp(-|x-x'|^2/(2*lam^2)) within an instance" if inst else ""),
        "classes": self.classes, "components": self.components,
        "component_names": self.component_names, "input_dim": self.input_dim,
        "files": files, "sha256": digests, "hyperparameters": self.hyperparameters(), "meta": self.meta,
    }
    return write_index(folder / INDEX, index, extra)


def read_bank_index(folder: str | Path) -> dict:
    """A GP bank folder's index.json, its format, version and structure checked, or a
    ModelFileError naming the file."""
    ipath = Path(folder) / INDEX
    index = read_index(ipath, FORMAT, VERSION, ("classes", "components", "files"), ModelFileError, "model index")
    _check_shapes(ipath, index)
    return index


def load_bank(folder: str | Path) -> GPClassModels:
    """A GPClassModels bank from ``folder``: index, per-class digests and arrays checked, or a
    ModelFileError naming the file."""
    folder = Path(folder)
    ipath = folder / INDEX
    index = read_bank_index(folder)
    comps = [int(i) for i in index["components"]]
    arrays: dict[str, list] = {k: [] for k in ("X", "Y", "mean", "amplitude", "length_scale", "noise")}
    inst: dict[str, list] = {k: [] for k in INSTANCE_ARRAYS}
    for name in index["classes"]:
        fname = index["files"].get(name)
        if not isinstance(fname, str) or not fname or "/" in fname or "\\" in fname:
            raise ModelFileError(ipath, f"no valid file entry for class {name!r}")
        path = inside(folder, fname, ipath, ModelFileError, f"the file of class {name!r}")
        if not path.is_file():
            raise ModelFileError(path, f"model file of class {name!r} not found")
        _check_digest(ipath, index, fname)
        try:
            data = load_npz(path)
        except NpzFileError as e:
            raise ModelFileError(path, f"unreadable model file: {e.problem}") from None
        for k in list(arrays) + ["components"]:
            if k not in data:
                raise ModelFileError(path, f"missing array '{k}'")
        if [int(i) for i in data["components"]] != comps:
            raise ModelFileError(path, f"components {data['components'].tolist()} differ from the index {comps}")
        for k in arrays:
            arrays[k].append(data[k])
        has = {k in data for k in INSTANCE_ARRAYS}
        if len(has) > 1 or (len(arrays["X"]) > 1 and has != {bool(inst["instances"])}):
            raise ModelFileError(path, f"the instance term's arrays ({', '.join(INSTANCE_ARRAYS)}) must be in every "
                                       "class file of a bank or in none")
        for k in INSTANCE_ARRAYS:
            if k in data:
                inst[k].append(data[k])
    try:
        plain = GPClassModels(index["classes"], comps, arrays["X"], arrays["Y"],
                              np.stack(arrays["mean"]), np.stack(arrays["amplitude"]),
                              np.stack(arrays["length_scale"]), np.stack(arrays["noise"]),
                              component_names=index.get("component_names"), meta=index.get("meta"))
        if not inst["instances"]:
            return plain
        return InstanceGPClassModels.from_plain(plain, inst["instances"], np.stack(inst["instance_amplitude"]),
                                                np.stack(inst["instance_length_scale"]))
    except ValueError as e:
        raise ModelFileError(folder, f"inconsistent model files: {e}") from None


def _check_shapes(ipath: Path, index: dict) -> None:
    """The index's own structure, before anything indexes into it: classes a non-empty list of
    names, components a non-empty list of integers, files and sha256 objects."""
    classes, comps = index["classes"], index["components"]
    if not isinstance(classes, list) or not classes or not all(isinstance(c, str) and c for c in classes):
        raise ModelFileError(ipath, f"'classes' must be a non-empty list of names, got {classes!r:.80}")
    if (not isinstance(comps, list) or not comps
            or not all(isinstance(i, int) and not isinstance(i, bool) for i in comps)):
        raise ModelFileError(ipath, f"'components' must be a non-empty list of integers, got {comps!r:.80}")
    for key in ("files", "sha256"):
        if key in index and not isinstance(index[key], dict):
            raise ModelFileError(ipath, f"'{key}' must be an object (class -> file), got {type(index[key]).__name__}")
    ablations = index.get("ablations", {})
    if not isinstance(ablations, dict):
        raise ModelFileError(ipath, f"'ablations' must be an object (ablation -> folder), got {type(ablations).__name__}")
    for name, sub in ablations.items():   # each bank folder stays inside this one
        inside(ipath.parent, sub, ipath, ModelFileError, f"'ablations' entry {name!r}")


def _check_digest(ipath: Path, index: dict, fname: str) -> None:
    """The file's sha256 must be the one index.json recorded when the models were saved: a file
    swapped with another class's, or rewritten, is an error naming both files."""
    recorded = index.get("sha256")
    if recorded is None:
        return  # written before digests were recorded
    if not isinstance(recorded, dict) or fname not in recorded:
        raise ModelFileError(ipath, f"no sha256 recorded for {fname!r}")
    path = ipath.parent / fname
    actual = sha256_file(path)
    if actual == recorded[fname]:
        return
    other = [f for f, h in recorded.items() if h == actual and f != fname]
    if other:
        raise ModelFileError(path, f"holds the content index.json records for {ipath.parent / other[0]} "
                                   f"(files swapped or copied?); rerun the 'models' stage")
    raise ModelFileError(path, f"content differs from the sha256 recorded in {ipath} "
                               "(file changed after the models were saved); rerun the 'models' stage")


def _file_names(classes: Sequence[str]) -> dict[str, str]:
    """A safe, unique file name per class (class names are folder names, but be careful)."""
    out, used = {}, set()
    for i, cls in enumerate(classes):
        base = re.sub(r"[^A-Za-z0-9._-]", "_", cls).strip(".") or f"class_{i}"
        name = f"{base}.npz"
        if name.lower() in used or name == INDEX:
            name = f"{base}_{i}.npz"
        used.add(name.lower())
        out[cls] = name
    return out
