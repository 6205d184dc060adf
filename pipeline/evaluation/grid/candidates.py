"""Which classes compete with each target (the candidate set), and which components model them.

The paper evaluated one target against three other instances. The population evaluation repeats
that for every target with its own candidate set: the target plus ``n_candidates - 1`` others
drawn from the modelled classes with a seed per target (so adding a target does not change the
others' draws), every modelled class, an explicit list, or the ``n_candidates - 1`` classes
hardest to tell from the target (``"hard"``).

Hard sets: a class's position in score space is the mean, over its training views, of the
deterministic-pass score vector (the classifier's probability vector); the distance between two
classes is the Euclidean distance between their positions, and a target's hard set is the target
plus the ``n_candidates - 1`` other classes nearest to it, ties broken by class name. Distances
are taken from the target, so the relation need not be symmetric (B may be among A's nearest and
not A among B's). Candidates are kept in name order, so
the truth's position in the posterior varies between targets: ``argmax`` breaks ties towards the
lower index, and a fixed truth position would bias ties.

Components: each set's N_f is ``models.n_components``; with every class as a candidate
(``"all"``) it grows with the set, at least one component per candidate (``set_size``): the
paper's N_f = N_c (section 4.4.1), so eight candidates are not told apart on four numbers.
Rule ``explicit`` keeps the components it names.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from pipeline.method.components import choose_components
from pipeline.scene.folds import FOLD_SEP, fold_of  # noqa: F401 - public here
from pipeline.infra import seeds
from pipeline.infra.config.fields import ConfigError


def nearest_classes(target: str, others: Sequence[str], class_means: Mapping[str, np.ndarray],
                    k: int) -> list[str]:
    """The ``k`` classes of ``others`` nearest to ``target`` (Euclidean distance between the class
    mean score vectors), nearest first; equal distances in name order."""
    centre = np.asarray(class_means[target], float)
    dist = {c: float(np.linalg.norm(np.asarray(class_means[c], float) - centre)) for c in others}
    return sorted(others, key=lambda c: (dist[c], c))[:k]


def candidate_sets(pool: Sequence[str], targets: Sequence[str], n_candidates: int,
                   candidates: str | Sequence[str], seed: int,
                   class_means: Mapping[str, np.ndarray] | None = None,
                   folds: bool = False) -> dict[str, list[str]]:
    """{target: sorted candidate classes (the target among them)}.

    ``candidates``: ``"sampled"``, ``"all"``, ``"hard"`` or a list of the other candidates (used as
    given for every target; ``n_candidates`` is then ignored). ``"hard"`` needs ``class_means``:
    each modelled class's mean deterministic-pass score vector over its training views. With
    ``folds``, every choice is made among the classes of the target's own fold (``fold_of``): the
    other folds' classes were fitted on the target's own photographs.
    """
    pool = sorted(set(pool))
    if folds:
        out: dict[str, list[str]] = {}
        for t in targets:
            same = [c for c in pool if fold_of(c) == fold_of(t)]
            given = candidates if isinstance(candidates, str) else [c for c in candidates if fold_of(c) == fold_of(t)]
            out.update(candidate_sets(same, [t], n_candidates, given, seed, class_means))
        return out
    if candidates == "hard":
        lack = [c for c in pool if class_means is None or c not in class_means]
        if lack:
            raise ValueError(f"'evaluate.candidates' = 'hard' needs the mean score vector of every modelled class; "
                             f"{lack[0]!r} has none")
        dims = {np.asarray(class_means[c]).shape for c in pool}
        if len(dims) != 1 or len(next(iter(dims))) != 1:
            raise ValueError(f"'evaluate.candidates' = 'hard': class mean score vectors must be 1-D of one length "
                             f"(got shapes {sorted(dims)})")
    out: dict[str, list[str]] = {}
    for t in targets:
        if t not in pool:
            raise ValueError(f"target {t!r} is not a modelled class (modelled: {', '.join(pool)})")
        others = [c for c in pool if c != t]
        if candidates == "all":
            picked = others
        elif candidates in ("sampled", "hard"):
            if n_candidates - 1 > len(others):
                raise ConfigError(f"'evaluate.n_candidates' = {n_candidates} but only {len(pool)} classes are "
                                  f"modelled ({', '.join(pool)})")
            if candidates == "hard":
                out[t] = sorted([t, *nearest_classes(t, others, class_means, n_candidates - 1)])
                continue
            rng = seeds.stream(seed, t)
            picked = [others[i] for i in rng.choice(len(others), n_candidates - 1, replace=False)]
        else:
            unknown = [c for c in candidates if c not in pool]
            if unknown:
                raise ValueError(f"'evaluate.candidates' names {unknown[0]!r}, which is not a modelled class")
            picked = [c for c in candidates if c != t]
        out[t] = sorted([t, *picked])
    return out


def set_size(n: int, n_classes: int, per_candidate: bool, rule: str = "top_mean") -> int:
    """N_f of one candidate set: ``n`` (models.n_components), or with ``per_candidate`` at least one
    component per candidate (the paper's N_f = N_c, section 4.4.1: ``evaluate.candidates = "all"``).
    Rule ``explicit`` keeps the components it names: the user chose N_f."""
    return max(int(n), int(n_classes)) if per_candidate and rule != "explicit" else int(n)


def plan_components(sets: Mapping[str, Sequence[str]], scores_by_class: Mapping[str, np.ndarray], n: int,
                    rule: str, explicit: Sequence[int] = (), informative_min: float = 0.02,
                    per_candidate: bool = False) -> dict[str, dict]:
    """Per target: the N_f components chosen by ``rule`` on its candidates' training scores; N_f is
    ``set_size`` (``per_candidate``: never fewer components than candidates)."""
    out = {}
    for target, classes in sets.items():
        k = set_size(n, len(classes), per_candidate, rule)
        comps, record = choose_components([scores_by_class[c] for c in classes], k, rule, explicit,
                                          target=list(classes).index(target), informative_min=informative_min)
        out[target] = {"classes": list(classes), "components": comps, "choice": record}
    return out


def own_components(scores_by_class: Mapping[str, np.ndarray]) -> dict[str, int]:
    """Each class's own score component for Simple Bayes: where its mean training score peaks."""
    return {c: int(np.argmax(np.asarray(s, float).mean(axis=0))) for c, s in scores_by_class.items()}
