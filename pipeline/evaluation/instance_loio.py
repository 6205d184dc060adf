"""Leave-one-instance-out judgement of the instance term's prior (docs/results.md, "Instance term:
a prior on the variance split"; ``tools/instance_loio.py`` runs it on a features file).

Data: per category, per instance, its turntable views' GP inputs X (n, 2) and classifier
probabilities S (n, D). Fold k holds out the k-th instance of every category (the category
benchmark's folds); the class GPs of every category are fitted on the other instances in three
variants (``VARIANTS``): the plain class GP, the instance term with no prior on b and λ, and the
instance term with ``instance_prior = "split"``. Each held-out instance is then scored by its own
category's fit: per component, the joint Gaussian predictive of its n views (``GPClassModels.predict``,
the instance term's k_h included) gives the log predictive density of the n scores (per view: the
joint log density / n) and each view's z = (y - μ) / sd. Components per fold: each category's
``top`` highest mean training probabilities, pooled over the categories (so every category is
fitted on every pooled component, as a candidate set's bank is). Summaries: over every pooled
component ("all": most are other categories' components, near 0 for this one) and over each
category's own ``top`` ("own": where its scores carry the viewpoint signal).

The unit is a held-out (category, instance): its mean over components and views. Every figure's
95 % interval is a bootstrap over categories, then their instances (``statistics.resampler``);
differences between variants are paired (the same draws of the same units).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from pipeline.evaluation.statistics.resampler import draws, estimate
from pipeline.method import score_space
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.gp_instance_fit import Z95, fit_instance_models

VARIANTS = ("plain", "instance_none", "instance_split")
QUANTILES = (0.5, 0.9, 0.99)


@dataclass
class Settings:
    """The fit settings of every variant (``fit_class_models``' keywords) and the judgement's own:
    ``space`` (``models.score_space``), ``floor``, ``top`` components per category, ``split_prior``
    (the Beta shapes of b / (a + b)), ``n_boot`` and ``seed`` of the bootstrap."""
    space: str = "probability"
    floor: float = score_space.DEFAULT_FLOOR
    top: int = 2
    split_prior: tuple[float, float] = (2.0, 2.0)
    fit: dict = field(default_factory=dict)
    n_boot: int = 2000
    seed: int = 0


def fold_data(data: Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]], k: int):
    """Fold k: per category (sorted), the training X, S, instance labels of every instance but its
    k-th (sorted by name), and the held-out instance's (name, X, S)."""
    train, held = {}, {}
    for cat in sorted(data):
        names = sorted(data[cat])
        out = names[k]
        keep = [n for n in names if n != out]
        train[cat] = (np.concatenate([data[cat][n][0] for n in keep]),
                      np.concatenate([data[cat][n][1] for n in keep]),
                      np.concatenate([np.full(len(data[cat][n][0]), i) for i, n in enumerate(keep)]))
        held[cat] = (out, *data[cat][out])
    return train, held


def fold_components(train: dict, top: int) -> dict[str, list[int]]:
    """Each category's ``top`` components by mean training probability (its own)."""
    return {cat: [int(i) for i in np.argsort(-S.mean(axis=0), kind="stable")[:top]] for cat, (X, S, _) in train.items()}


def judge_fold(train: dict, held: dict, st: Settings) -> tuple[list[dict], list[dict]]:
    """The three variants' fits on one fold and their scores of the held-out instances: (one row per
    (variant, category, component) of the held-out scores, the instance fits' records)."""
    cats = sorted(train)
    own = fold_components(train, st.top)
    comps = sorted({i for v in own.values() for i in v})
    Xs = [train[c][0] for c in cats]
    Ys = [score_space.to_space(train[c][1], st.space, st.floor)[:, comps].T for c in cats]
    labels = [train[c][2] for c in cats]
    kw = dict(classes=cats, components=comps, progress=False, **st.fit)
    fits = {"plain": fit_class_models(Xs, Ys, **kw)[0]}
    records = []
    for prior, name in (("none", "instance_none"), ("split", "instance_split")):
        models, diags = fit_instance_models(Xs, Ys, labels, instance_prior=prior, split_prior=st.split_prior, **kw)
        fits[name] = models
        records += [dict(d, variant=name, own=int(d["component"]) in own[d["class"]]) for d in diags]
    rows = []
    for ci, cat in enumerate(cats):
        name, X, S = held[cat]
        Y = score_space.to_space(S, st.space, st.floor)[:, comps].T            # (F, n)
        for variant, models in fits.items():
            mu, cov = models.predict(X[None])                                  # (1, C, F, n), (1, C, F, n, n)
            for fi, comp in enumerate(comps):
                lpd, z = _scores(Y[fi], mu[0, ci, fi], cov[0, ci, fi])
                rows.append({"variant": variant, "category": cat, "instance": name, "component": comp,
                             "own": comp in own[cat], "lpd_per_view": lpd / len(z), "z": z})
    return rows, records


def _scores(y: np.ndarray, mu: np.ndarray, cov: np.ndarray) -> tuple[float, np.ndarray]:
    """The joint Gaussian log density of y and each view's z."""
    L = np.linalg.cholesky(cov)
    w = np.linalg.solve(L, y - mu)
    lpd = -0.5 * w @ w - np.log(np.diag(L)).sum() - 0.5 * len(y) * np.log(2 * np.pi)
    return float(lpd), (y - mu) / np.sqrt(np.diag(cov))


def judge(data: Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray]]], st: Settings) -> dict:
    """Every fold (as many as the fewest instances of a category) -> the summary (``summarise``)."""
    n_folds = min(len(v) for v in data.values())
    rows, records = [], []
    for k in range(n_folds):
        r, d = judge_fold(*fold_data(data, k), st)
        rows += r
        records += [dict(x, fold=k) for x in d]
    return {"all": summarise(rows, records, st),
            "own": summarise([r for r in rows if r["own"]], [d for d in records if d["own"]], st)}


def bound_counts(records: list[dict]) -> dict:
    """Per instance variant: fits with a term, and how many sit at each bound (from ``at_bound``)."""
    out = {}
    for v in ("instance_none", "instance_split"):
        fits = [d for d in records if d["variant"] == v and d["instance_term"]]
        at = {}
        for d in fits:
            for b in d["at_bound"]:
                at[b] = at.get(b, 0) + 1
        ratio = np.array([d["instance_amplitude"] / (d["amplitude"] + d["instance_amplitude"]) for d in fits])
        out[v] = {"fits": len(fits), "at_bound": dict(sorted(at.items())),
                  "any_instance_bound": sum(any(b.startswith("instance_") for b in d["at_bound"]) for d in fits),
                  "split_quartiles": [float(q) for q in np.quantile(ratio, [0.25, 0.5, 0.75])] if len(fits) else None}
    return out


def summarise(rows: list[dict], records: list[dict], st: Settings) -> dict:
    """Per variant: mean log predictive density per view, 95 % coverage (share of views with |z| <
    1.96) and |z| quantiles; paired differences of the first two between variants. Intervals: the
    bootstrap over categories, then instances, of the (category, instance) units' means."""
    cats = sorted({r["category"] for r in rows})
    insts = {c: sorted({r["instance"] for r in rows if r["category"] == c}) for c in cats}
    rs = draws([[1] * len(insts[c]) for c in cats], st.n_boot, st.seed)
    T = max(len(v) for v in insts.values())

    def units(variant: str, stat) -> np.ndarray:
        v = np.full((len(cats), T, 1), np.nan)
        for i, c in enumerate(cats):
            for j, n in enumerate(insts[c]):
                v[i, j, 0] = stat([r for r in rows if r["variant"] == variant and r["category"] == c
                                   and r["instance"] == n])
        return v

    stats = {"lpd_per_view": lambda rr: float(np.mean([r["lpd_per_view"] for r in rr])),
             "coverage95": lambda rr: float(np.mean(np.abs(np.concatenate([r["z"] for r in rr])) < Z95))}
    vals = {v: {s: units(v, f) for s, f in stats.items()} for v in VARIANTS}

    def est(x):
        return estimate(rs.point(x, "mean"), rs.draws(x, "mean"))

    out = {"space": st.space, "categories": len(cats), "instances": sum(len(v) for v in insts.values()),
           "components_per_fold": sorted({len({r["component"] for r in rows if r["instance"] == n})
                                          for c in cats for n in insts[c]}),
           "over": "categories, then their held-out instances (bootstrap, %d draws)" % st.n_boot,
           "variants": {}, "differences": {}, "bounds": bound_counts(records)}
    for v in VARIANTS:
        z = np.abs(np.concatenate([r["z"] for r in rows if r["variant"] == v]))
        out["variants"][v] = {s: est(vals[v][s]) for s in stats}
        out["variants"][v]["abs_z_quantiles"] = {str(q): float(np.quantile(z, q)) for q in QUANTILES}
    for a, b in (("instance_split", "instance_none"), ("instance_split", "plain"), ("instance_none", "plain")):
        out["differences"][f"{a} - {b}"] = {s: est(vals[a][s] - vals[b][s]) for s in stats}
    return out
