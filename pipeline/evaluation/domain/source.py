"""Is the MC-dropout spread a usable model-uncertainty source? How well a crop's dropout spread
ranks how far its scores fall from its own class model.

Per labelled crop (rows of ``domain.fit.crop_residuals``, one per crop and GP component): the
spread is the standard deviation of its MC samples per component, averaged over the components;
|z| is |mean score − GP predictive mean| / GP predictive sd (σ_n² included) at the crop's true class
and true viewing direction, averaged over the components. Two statistics: Spearman ρ between spread
and |z|, and the AUROC of the spread for a crop whose |z| exceeds 2 (0.5: the spread does not rank
far-off crops first). Each with a 95 % percentile CI from the statistics engine's resampler, one
level: the classes (the design's clusters: objects at instance level, categories at category
level) drawn with replacement, each drawn class bringing all of its crops.

Pooled across classes, both statistics also measure which classes fit badly (a class whose model
fails puts most of its crops beyond |z| = 2 and may have a wide spread throughout), so the
question "does the spread flag a bad crop?" is answered within each class (``within_class``): ρ
and AUROC per class, pooled over classes by stratification, their spread over the classes, and
95 % CIs from the same class bootstrap.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.stats import rankdata

from pipeline.evaluation.statistics.resampler import draws, estimate

Z_FAR = 2.0


def per_crop(table: pd.DataFrame) -> pd.DataFrame:
    """One row per crop: instance (its class), spread (mean over components of the MC samples' sd)
    and abs_z (mean over components of |obs − mu| / sqrt(var))."""
    if table.empty:
        return pd.DataFrame({"instance": [], "spread": [], "abs_z": []})
    t = table.assign(sd=np.sqrt(table["v_z"].to_numpy(float)),
                     az=np.abs(table["obs"].to_numpy(float) - table["mu"].to_numpy(float))
                     / np.sqrt(table["var"].to_numpy(float)))
    g = t.groupby(["scan", "instance", "image"], sort=True)
    return pd.DataFrame({"instance": g["instance"].first(), "spread": g["sd"].mean(),
                         "abs_z": g["az"].mean()}).reset_index(drop=True)


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman ρ (average ranks for ties); NaN when either side is constant or n < 3."""
    if len(x) < 3:
        return float("nan")
    rx, ry = rankdata(x), rankdata(y)
    sx, sy = rx.std(), ry.std()
    if sx == 0 or sy == 0:
        return float("nan")
    return float(np.mean((rx - rx.mean()) * (ry - ry.mean())) / (sx * sy))


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """P(score of a positive > score of a negative), ties counting half (Mann–Whitney); NaN
    without positives or without negatives."""
    positive = np.asarray(positive, bool)
    n1 = int(positive.sum())
    n0 = len(positive) - n1
    if n1 == 0 or n0 == 0:
        return float("nan")
    r = rankdata(score)
    return float((r[positive].sum() - n1 * (n1 + 1) / 2.0) / (n1 * n0))


def crop_statistics(spread: np.ndarray, abs_z: np.ndarray) -> tuple[float, float]:
    return spearman(spread, abs_z), auroc(spread, abs_z > Z_FAR)


class WeightedStatistics:
    """ρ and the AUROC of a resample given as multiplicities (each drawn class's crops counted as
    often as it was drawn): the same numbers as on the expanded sample, without re-sorting it. Ties
    keep their average rank: a group of equal values of total weight W after weight S ranks S + (W + 1) / 2."""

    def __init__(self, spread: np.ndarray, abs_z: np.ndarray):
        _, self.gx = np.unique(spread, return_inverse=True)
        _, self.gy = np.unique(abs_z, return_inverse=True)
        self.far = abs_z > Z_FAR

    @staticmethod
    def _ranks(groups: np.ndarray, w: np.ndarray) -> np.ndarray:
        gw = np.bincount(groups, weights=w)
        return (np.cumsum(gw) - gw + (gw + 1.0) / 2.0)[groups]

    def __call__(self, w: np.ndarray) -> tuple[float, float]:
        # elementwise sums, not BLAS dot products: a threaded BLAS on a busy machine made each
        # of these vector products cost milliseconds
        n = w.sum()
        rx, ry = self._ranks(self.gx, w), self._ranks(self.gy, w)
        dx, dy = rx - (w * rx).sum() / n, ry - (w * ry).sum() / n
        sxx, syy = (w * dx * dx).sum(), (w * dy * dy).sum()
        rho = float((w * dx * dy).sum() / np.sqrt(sxx * syy)) if n >= 3 and sxx > 0 and syy > 0 else float("nan")
        n1 = w[self.far].sum()
        n0 = n - n1
        auc = float(((w * rx)[self.far].sum() - n1 * (n1 + 1) / 2.0) / (n1 * n0)) if n1 > 0 and n0 > 0 \
            else float("nan")
        return rho, auc


def per_class(spread: np.ndarray, abs_z: np.ndarray, members: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Per class: crops n, ρ, AUROC (NaN where undefined: under 3 crops, a constant side, no crop on
    one side of |z| = 2), the AUROC's pair count n_far x n_near, and the share of crops with |z| > 2."""
    rho = np.array([spearman(spread[m], abs_z[m]) for m in members])
    far = [abs_z[m] > Z_FAR for m in members]
    auc = np.array([auroc(spread[m], f) for m, f in zip(members, far)])
    pairs = np.array([float(f.sum() * (len(f) - f.sum())) for f in far])
    return {"n": np.array([len(m) for m in members], float), "rho": rho, "auroc": auc, "pairs": pairs,
            "far_share": np.array([float(f.mean()) for f in far])}


def stratified(pc: dict[str, np.ndarray], w: np.ndarray) -> tuple[float, float]:
    """The within-class statistics pooled over classes by stratification, each class counted ``w``
    times: ρ as the crop-weighted mean of the classes' ρ, the AUROC over within-class pairs only
    (the classes' AUROCs weighted by their pair counts; van Elteren's stratified Mann–Whitney)."""
    ok_r, ok_a = ~np.isnan(pc["rho"]) & (w > 0), ~np.isnan(pc["auroc"]) & (w > 0)
    wr, wa = (w * pc["n"])[ok_r], (w * pc["pairs"])[ok_a]
    rho = float((wr * pc["rho"][ok_r]).sum() / wr.sum()) if wr.sum() > 0 else float("nan")
    auc = float((wa * pc["auroc"][ok_a]).sum() / wa.sum()) if wa.sum() > 0 else float("nan")
    return rho, auc


def _spread_of(x: np.ndarray) -> dict:
    v = x[~np.isnan(x)]
    if not len(v):
        return {"n_classes": 0}
    return {"n_classes": int(len(v)), "min": float(v.min()), "median": float(np.median(v)), "max": float(v.max())}


def within_class(spread: np.ndarray, abs_z: np.ndarray, members: list[np.ndarray], n_boot: int, seed: int) -> dict:
    """ρ and AUROC within each class, pooled over classes by stratification, with their spread over
    the classes and 95 % CIs from resampling classes (each drawn class with all its crops)."""
    pc = per_class(spread, abs_z, members)
    k = len(members)
    rho, auc = stratified(pc, np.ones(k))
    far = np.sort(pc["far_share"] * pc["n"])[::-1]
    out = {"how": "per class, then pooled over classes by stratification: rho as the crop-weighted mean of the "
                  "classes' rho, the AUROC over pairs of crops of the same class",
           "over": "classes (each with all its crops)", "rho_spread": _spread_of(pc["rho"]),
           "auroc_spread": _spread_of(pc["auroc"]), "max_class_far_share": float(np.max(pc["far_share"])),
           "top2_far_share": float(far[:2].sum() / far.sum()) if far.sum() > 0 else float("nan")}
    if k < 2:
        return {**out, "rho": estimate(rho, None), "auroc": estimate(auc, None), "n_boot": 0}
    rs = draws([[1] * k], n_boot, seed)
    bd = np.array([stratified(pc, np.bincount(rs.pt[b, 0], minlength=k).astype(float)) for b in range(rs.n_boot)])
    out.update(rho=estimate(rho, bd[:, 0]), auroc=estimate(auc, bd[:, 1]), n_boot=int(rs.n_boot))
    undefined = int(np.isnan(bd[:, 1]).sum())
    if undefined:   # the engine's rule: an undefined draw leaves no interval; say why
        out["auroc_note"] = (f"no CI: {undefined} of {rs.n_boot} resamples draw only classes without a crop on both "
                             f"sides of |z| = {Z_FAR:g}")
    return out


def source_summary(crops: pd.DataFrame, n_boot: int, seed: int) -> dict:
    """ρ and AUROC with their CIs over classes, the counts behind them (JSON-ready)."""
    n = len(crops)
    if n < 3:
        return {"n_crops": n, "note": "fewer than 3 labelled crops: no ranking to measure"}
    classes = sorted(set(crops["instance"]))
    members = [np.flatnonzero(crops["instance"].to_numpy() == c) for c in classes]
    spread, abs_z = crops["spread"].to_numpy(float), crops["abs_z"].to_numpy(float)
    rho, auc = crop_statistics(spread, abs_z)
    out = {"n_crops": n, "n_classes": len(classes), "far": f"|z| > {Z_FAR:g}",
           "far_share": float(np.mean(abs_z > Z_FAR)), "over": "classes (each with all its crops)"}
    if len(classes) < 2:
        out.update(rho=estimate(rho, None), auroc=estimate(auc, None), n_boot=0,
                   within=within_class(spread, abs_z, members, n_boot, seed))
        return out
    # One level: the resampler's targets are the classes, each with one "track" (all its crops).
    rs = draws([[1] * len(classes)], n_boot, seed)
    of_crop = np.empty(n, dtype=np.int64)
    for c, m in enumerate(members):
        of_crop[m] = c
    stat = WeightedStatistics(spread, abs_z)
    bd = np.empty((rs.n_boot, 2))
    for b in range(rs.n_boot):
        bd[b] = stat(np.bincount(rs.pt[b, 0], minlength=len(classes))[of_crop].astype(float))
    out.update(rho=estimate(rho, bd[:, 0]), auroc=estimate(auc, bd[:, 1]), n_boot=int(rs.n_boot),
               within=within_class(spread, abs_z, members, n_boot, seed))
    undefined = int(np.isnan(bd[:, 1]).sum())
    if undefined:   # the engine's rule: an undefined draw leaves no interval; say why
        out["auroc_note"] = (f"no CI: {undefined} of {rs.n_boot} resamples hold no crop with |z| > {Z_FAR:g} "
                             "(or none within it)")
    return out


def reading(summary: dict) -> str:
    """One line: what the numbers say about the spread as the model-uncertainty source (computed)."""
    within = summary.get("within") or summary   # within each class where measured, else the pooled figure
    rho, auc = (within.get("rho") or {}), (within.get("auroc") or {})
    lo, hi = rho.get("ci_low"), rho.get("ci_high")
    if not within.get("rho") or lo is None or hi is None or not (np.isfinite(lo) and np.isfinite(hi)):
        return "too few crops or classes to say whether the spread tracks the distance from the class model"
    if lo > 0:
        what = "the spread ranks crops far from their class model higher (ρ's 95 % CI above 0)"
    elif hi < 0:
        what = "the spread ranks crops far from their class model lower (ρ's 95 % CI below 0): it points the wrong way"
    else:
        what = "no rank relation between the spread and the distance from the class model is shown (ρ's 95 % CI contains 0)"
    a_lo, a_hi = auc.get("ci_low"), auc.get("ci_high")
    if a_lo is not None and a_hi is not None and np.isfinite(a_lo) and np.isfinite(a_hi):
        what += ("; it flags |z| > 2 crops better than chance" if a_lo > 0.5 else
                 "; it flags |z| > 2 crops worse than chance" if a_hi < 0.5 else
                 "; it does not flag |z| > 2 crops better than chance (AUROC's CI contains 0.5)")
    scope = "within each class (pooled over classes by stratification): " if summary.get("within") else \
        "pooled across classes: "
    return scope + what
