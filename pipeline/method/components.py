"""Which score components the class GPs model (the paper's N_f "feature components").

The classifier's score vector has D entries (ImageNet: 1000). The paper keeps N_f = 4 components
that score high across the candidate classes' training views. Rules:
- ``top_mean``: highest mean score over all candidate classes' training views pooled;
- ``top_min``: highest minimum over classes of the per-class mean score (components every class
  responds to);
- ``target_informative``: as the paper describes its choice: components that score non-negligibly
  (per-class mean >= ``informative_min``) for every candidate, ranked by the target's own mean
  score; when fewer than n qualify, the rest follow in ``top_min`` order;
- ``explicit``: the given indices.
Ties break towards the lower index, so the choice is deterministic.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

RULES = ("top_mean", "top_min", "target_informative", "explicit")


def choose_components(scores_by_class: Sequence[np.ndarray], n: int, rule: str = "top_mean",
                      explicit: Sequence[int] = (), *, target: int = 0,
                      informative_min: float = 0.02) -> tuple[list[int], dict]:
    """Pick ``n`` component indices from per-class training scores (N_c, D).

    ``target`` is the index of the target class (rule ``target_informative``). Returns the indices
    (in rank order) and a record of the choice for the model index.
    """
    if rule not in RULES:
        raise ValueError(f"unknown component rule {rule!r} (known: {', '.join(RULES)})")
    mats = [np.asarray(s, dtype=float) for s in scores_by_class]
    if not mats or any(m.ndim != 2 or len(m) == 0 for m in mats):
        raise ValueError("choose_components: need a non-empty (N_c, D) score matrix per class")
    D = mats[0].shape[1]
    if any(m.shape[1] != D for m in mats):
        raise ValueError(f"choose_components: score dimensions differ: {[m.shape[1] for m in mats]}")
    if not 1 <= n <= D:
        raise ValueError(f"choose_components: n_components = {n} must be between 1 and the score dimension {D}")
    per_class = np.stack([m.mean(axis=0) for m in mats])                  # (C, D)
    pooled = np.concatenate(mats).mean(axis=0)                            # (D,)
    if rule == "explicit":
        comps = [int(i) for i in explicit]
        if len(comps) != n:
            raise ValueError(f"choose_components: rule 'explicit' needs {n} indices, got {len(comps)}")
        if len(set(comps)) != n or any(not 0 <= i < D for i in comps):
            raise ValueError(f"choose_components: explicit components {comps} must be distinct indices in [0, {D})")
        key = pooled
    elif rule == "target_informative":
        floor = per_class.min(axis=0)
        eligible = floor >= informative_min
        # Eligible components first (by the target's mean), then the rest by their weakest class.
        key = np.where(eligible, 1.0 + per_class[target], floor)
        comps = [int(i) for i in np.argsort(-key, kind="stable")[:n]]
    else:
        key = pooled if rule == "top_mean" else per_class.min(axis=0)
        comps = [int(i) for i in np.argsort(-key, kind="stable")[:n]]
    record = {
        "rule": rule,
        "n_components": n,
        "components": comps,
        "rule_score": [float(key[i]) for i in comps],
        "pooled_mean": [float(pooled[i]) for i in comps],
        "per_class_mean": [[float(per_class[c, i]) for i in comps] for c in range(len(mats))],
    }
    return comps, record
