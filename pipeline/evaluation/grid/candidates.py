"""Which classes compete with each target (the candidate set), and which components model them.

The paper evaluated one target against three other instances. The population evaluation repeats
that for every target with its own candidate set: the target plus ``n_candidates - 1`` others
drawn from the modelled classes with a seed per target (so adding a target does not change the
others' draws), every modelled class, or an explicit list. Candidates are kept in name order, so
the truth's position in the posterior varies between targets: ``argmax`` breaks ties towards the
lower index, and a fixed truth position would bias ties.
"""
from __future__ import annotations

import zlib
from typing import Mapping, Sequence

import numpy as np

from pipeline.method.components import choose_components


def candidate_sets(pool: Sequence[str], targets: Sequence[str], n_candidates: int,
                   candidates: str | Sequence[str], seed: int) -> dict[str, list[str]]:
    """{target: sorted candidate classes (the target among them)}.

    ``candidates``: ``"sampled"``, ``"all"`` or a list of the other candidates (used as given for
    every target; ``n_candidates`` is then ignored).
    """
    pool = sorted(set(pool))
    out: dict[str, list[str]] = {}
    for t in targets:
        if t not in pool:
            raise ValueError(f"target {t!r} is not a modelled class (modelled: {', '.join(pool)})")
        others = [c for c in pool if c != t]
        if candidates == "all":
            picked = others
        elif candidates == "sampled":
            if n_candidates - 1 > len(others):
                raise ValueError(f"'evaluate.n_candidates' = {n_candidates} but only {len(pool)} classes are modelled")
            rng = np.random.default_rng([seed, zlib.crc32(t.encode())])
            picked = [others[i] for i in rng.choice(len(others), n_candidates - 1, replace=False)]
        else:
            unknown = [c for c in candidates if c not in pool]
            if unknown:
                raise ValueError(f"'evaluate.candidates' names {unknown[0]!r}, which is not a modelled class")
            picked = [c for c in candidates if c != t]
        out[t] = sorted([t, *picked])
    return out


def plan_components(sets: Mapping[str, Sequence[str]], scores_by_class: Mapping[str, np.ndarray], n: int,
                    rule: str, explicit: Sequence[int] = (), informative_min: float = 0.02) -> dict[str, dict]:
    """Per target: the N_f components chosen by ``rule`` on its candidates' training scores."""
    out = {}
    for target, classes in sets.items():
        comps, record = choose_components([scores_by_class[c] for c in classes], n, rule, explicit,
                                          target=list(classes).index(target), informative_min=informative_min)
        out[target] = {"classes": list(classes), "components": comps, "choice": record}
    return out


def own_components(scores_by_class: Mapping[str, np.ndarray]) -> dict[str, int]:
    """Each class's own score component for Simple Bayes: where its mean training score peaks."""
    return {c: int(np.argmax(np.asarray(s, float).mean(axis=0))) for c, s in scores_by_class.items()}
