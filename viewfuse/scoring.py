"""Scoring images with a registered classifier, as the features stage scores crops: the entry
builds its network, loads a weights file (``.npz`` of plain arrays or a tensor-only torch file),
and MC dropout samples the head at the site the entry's network declares."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pipeline.scoring.classifiers import classifier


def mc_dropout_scores(arch: str, weights: str | Path, images, *, num_classes: int, dropout: float,
                      n_samples: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Softmax scores of ``images`` (B, 3, H, W), already normalised for the network, by the
    classifier ``arch`` (``vf.register_classifier``) with the weights in ``weights``:
    deterministic (B, D) and ``n_samples`` MC-dropout samples (B, N_s, D). Image ``i``'s masks come
    from its own stream (``seed``, ``i``), as each crop's do in the features stage."""
    import torch

    from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed  # heavy: torch
    from pipeline.scoring.weight_files import load_into, load_state_dict_file  # heavy: torch

    entry = classifier(arch)
    net = load_into(entry.build(int(num_classes), float(dropout)), load_state_dict_file(weights), weights,
                    entry.display)
    x = torch.as_tensor(np.asarray(images, np.float32))
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"mc_dropout_scores: images must be (B, 3, H, W), got {tuple(x.shape)}")
    scorer = MCDropoutScorer(net, onednn=False)
    det, mc = scorer.score(x, [crop_seed(seed, str(i)) for i in range(len(x))], int(n_samples))
    return det.numpy(), mc.numpy()
