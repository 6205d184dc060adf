"""Top-label ECE and the reliability diagram over the population's pooled posteriors.

ECE is not a mean of cell values: it bins every posterior of the population together. The
posteriors are weighted as every other pooled value is: within a track each setting weighs the
same and, within a setting, each realization (final step) or each (realization, step) (all steps);
every track of a target weighs the same, every target weighs the same. So a posterior of cell
(target t, track j, setting s) with R realizations weighs 1 / (T · n_t · S · R) at the final step.
The bootstrap resamples targets, then tracks within targets (``robust.Resample``); paired
differences use the same draws for both methods.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.evaluation.metrics import calibration as K
from pipeline.evaluation.statistics.robust import estimate, leave_one_out_values, resample

WHERE = ("final", "overall")


def cell_sums(posts: dict, truth: int) -> dict[str, np.ndarray]:
    """One cell's {method: (2, 3, n_bins + 1) bin sums (final, overall)} over its settings
    ``posts`` ({(experiment, label): {method: log posteriors (R, K, C)}}); each setting weighs
    1 / n_settings, each realization (final) or (realization, step) (overall) the same within it."""
    out: dict[str, np.ndarray] = {}
    n_set = len(posts)
    for by_method in posts.values():
        for method, lp in by_method.items():
            conf, ok = K.top_label(lp, truth)                  # (R, K)
            R, Kn = conf.shape
            s = np.stack([K.bin_sums(conf[:, -1], ok[:, -1], 1.0 / (n_set * R)),
                          K.bin_sums(conf, ok, 1.0 / (n_set * R * Kn))])
            out[method] = out.get(method, 0.0) + s
    return out


def track_sums(cells, results, variant: str) -> dict[tuple[str, str, int], np.ndarray]:
    """{(method, target, track): (2, 3, n_bins + 1) bin sums (final, overall)} for one variant;
    every track's weights sum to 1 for each of final and overall. A result holds its cell's
    ``cell_sums`` as ``calibration`` (the evaluate stage's streamed cells) or its ``posts``."""
    out: dict[tuple[str, str, int], np.ndarray] = {}
    for cell, res in zip(cells, results):
        if cell.variant != variant:
            continue
        sums = res["calibration"] if "calibration" in res else cell_sums(res["posts"], cell.truth)
        for method, s in sums.items():
            key = (method, cell.target, cell.track)
            out[key] = out.get(key, 0.0) + s
    return out


def _padded(sums: dict, method: str, targets: Sequence[str]) -> tuple[np.ndarray, list[int]]:
    per = [[v for (m, t, _), v in sorted(sums.items(), key=lambda kv: kv[0][2]) if m == method and t == tt]
           for tt in targets]
    sizes = [len(p) for p in per]
    shape = next(iter(sums.values())).shape
    out = np.zeros((len(targets), max(sizes)) + shape)
    for i, p in enumerate(per):
        for j, v in enumerate(p):
            out[i, j] = v
    return out, sizes


def _point_weights(sizes: Sequence[int]) -> np.ndarray:
    w = np.zeros((len(sizes), max(sizes)))
    for i, n in enumerate(sizes):
        w[i, :n] = 1.0 / (len(sizes) * n)
    return w


def _ece(weights: np.ndarray, padded: np.ndarray) -> np.ndarray:
    """ECE (..., 2) of weighted track sums: weights (..., T, W), padded (T, W, 2, 3, nb)."""
    return K.ece_from_sums(np.einsum("...tj,tjwkb->...wkb", weights, padded))


def pooled_ece(sums: dict, methods: Sequence[str], comparisons, n_boot: int, seed,
               per_target: bool = True, loto: bool = True) -> dict:
    """{"pooled": {method: {ece_final, ece_overall}}, "per_target": {target: {method: ...}},
    "paired": {comparison key: {ece_<where>: est + wins/losses over targets}}, "reliability":
    {method: {where: diagram}}}."""
    targets = sorted({t for (_, t, _) in sums})
    present = [m for m in methods if any(k[0] == m for k in sums)]
    if not targets or not present:
        return {"pooled": {}, "per_target": {}, "paired": {}, "reliability": {}}
    pads, sizes = {}, None
    for m in present:
        pads[m], sizes = _padded(sums, m, targets)
    rs = resample(sizes, n_boot, [*np.atleast_1d(seed), 7])
    bw = rs.member_weights()
    w0 = _point_weights(sizes)
    point = {m: _ece(w0, pads[m]) for m in present}
    boot = {m: _ece(bw, pads[m]) for m in present}
    out = {"pooled": {m: {f"ece_{w}": estimate(point[m][i], boot[m][:, i]) for i, w in enumerate(WHERE)}
                      for m in present},
           "per_target": {}, "paired": {}, "paired_per_target": {},
           "reliability": {m: {w: K.reliability(np.einsum("tj,tjwkb->wkb", w0, pads[m])[i])
                               for i, w in enumerate(WHERE)} for m in present}}
    tgt = {}
    for ti, t in enumerate(targets):
        n = sizes[ti]
        one = resample([n], n_boot, [*np.atleast_1d(seed), 8, ti]).member_weights()   # (B, 1, n)
        wt = np.full((1, n), 1.0 / n)
        for m in present:
            p = pads[m][ti: ti + 1, :n]
            val, bt = _ece(wt, p), _ece(one, p)
            tgt.setdefault(t, {})[m] = {f"ece_{w}": estimate(val[i], bt[:, i]) if n > 1 else
                                        {"value": float(val[i]), "ci_low": float("nan"), "ci_high": float("nan")}
                                        for i, w in enumerate(WHERE)}
    if per_target:
        out["per_target"] = tgt
    for a, b in comparisons:
        if a not in pads or b not in pads:
            continue
        key = f"{a}-{b}"
        res, res_t = {}, {}
        for i, w in enumerate(WHERE):
            d_t = np.array([tgt[t][a][f"ece_{w}"]["value"] - tgt[t][b][f"ece_{w}"]["value"] for t in targets])
            est = estimate(point[a][i] - point[b][i], boot[a][:, i] - boot[b][:, i])
            res[f"ece_{w}"] = {**est, "wins": float(np.mean(d_t < 0)), "losses": float(np.mean(d_t > 0)),
                               "n_cells": len(targets), "unit": "targets", "better": "lower"}
            if loto:
                res[f"ece_{w}"].update(leave_one_out_values(
                    targets, lambda keep, i=i: _loto_diff(keep, pads[a], pads[b], sizes, n_boot, seed, i), False))
            for t in targets:
                res_t.setdefault(t, {})[f"ece_{w}"] = {
                    "value": tgt[t][a][f"ece_{w}"]["value"] - tgt[t][b][f"ece_{w}"]["value"],
                    "ci_low": float("nan"), "ci_high": float("nan")}
        out["paired"][key] = res
        out["paired_per_target"][key] = res_t
    return out


def _loto_diff(keep: np.ndarray, pa: np.ndarray, pb: np.ndarray, sizes, n_boot: int, seed, i: int) -> dict:
    """ECE difference (estimate with CI) on the targets ``keep`` (indices)."""
    sz = [sizes[k] for k in keep]
    pa, pb = pa[keep], pb[keep]
    bw = resample(sz, n_boot, [*np.atleast_1d(seed), 9]).member_weights()
    w0 = _point_weights(sz)
    return estimate(_ece(w0, pa)[i] - _ece(w0, pb)[i], _ece(bw, pa)[:, i] - _ece(bw, pb)[:, i])
