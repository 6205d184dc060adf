"""Top-label ECE and the reliability diagram over the population's pooled posteriors.

ECE is not a mean of cell values: it bins every posterior of the population together. The
posteriors are weighted as every other pooled value is: within a track each setting weighs the
same and, within a setting, each realization (final step) or each (realization, step) (all steps);
every track of a target weighs the same, every target weighs the same. So a posterior of cell
(target t, track j, setting s) with R realizations weighs 1 / (T · n_t · S · R) at the final step.
The interval comes from the engine's shared draws (``hierarchy.Hierarchy``: the leaf weights of the
same targets -> tracks resamples every other metric uses); paired differences use the same draws
for both methods.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pipeline.evaluation.metrics import calibration as K
from pipeline.evaluation.statistics.resampler import estimate

WHERE = ("final", "overall")


def cell_sums(posts: dict, truth: int, n_bins: int) -> dict[str, np.ndarray]:
    """One cell's {method: (2, 3, n_bins + 1) bin sums (final, overall)} over its settings
    ``posts`` ({(experiment, label): {method: log posteriors (R, K, C)}}); each setting weighs
    1 / n_settings, each realization (final) or (realization, step) (overall) the same within it."""
    out: dict[str, np.ndarray] = {}
    n_set = len(posts)
    for by_method in posts.values():
        for method, lp in by_method.items():
            conf, ok = K.top_label(lp, truth)                  # (R, K)
            R, Kn = conf.shape
            s = np.stack([K.bin_sums(conf[:, -1], ok[:, -1], 1.0 / (n_set * R), n_bins),
                          K.bin_sums(conf, ok, 1.0 / (n_set * R * Kn), n_bins)])
            out[method] = out.get(method, 0.0) + s
    return out


def track_sums(cells, results, variant: str, n_bins: int) -> dict[tuple[str, str, int], np.ndarray]:
    """{(method, target, track): (2, 3, n_bins + 1) bin sums (final, overall)} for one variant;
    every track's weights sum to 1 for each of final and overall. A result holds its cell's
    ``cell_sums`` as ``calibration`` (the evaluate stage's streamed cells) or its ``posts``."""
    out: dict[tuple[str, str, int], np.ndarray] = {}
    for cell, res in zip(cells, results):
        if cell.variant != variant:
            continue
        sums = res["calibration"] if "calibration" in res else cell_sums(res["posts"], cell.truth, n_bins)
        for method, s in sums.items():
            key = (method, cell.target, cell.track)
            out[key] = out.get(key, 0.0) + s
    return out


def hierarchy_of(sums: dict, n_boot: int, seed):
    """The ``hierarchy.Hierarchy`` of the (target, track) units in track sums (when no cell table
    gives it: the evaluate stage's blocks take the one of their cells)."""
    import pandas as pd

    from pipeline.evaluation.statistics.hierarchy import Hierarchy  # heavy: pandas

    units = sorted({(t, tr) for (_, t, tr) in sums})
    return Hierarchy({"run": pd.DataFrame(units, columns=["target", "track"])}, n_boot, seed)


def _padded(h, sums: dict, method: str) -> np.ndarray:
    """(T, W, 2, 3, nb) track sums of ``method`` in the hierarchy's (target, track) positions."""
    shape = next(iter(sums.values())).shape
    _, T, W = h.target_rs.shape
    out = np.zeros((T, W) + shape)
    for (m, t, tr), v in sums.items():
        if m == method and (t, tr) in h.index[0]:
            ti, j = h.index[0][(t, tr)]
            out[ti, j] = v
    return out


def _ece(weights: np.ndarray, padded: np.ndarray) -> np.ndarray:
    """ECE (..., 2) of weighted track sums: weights (..., T, W), padded (T, W, 2, 3, nb)."""
    return K.ece_from_sums(np.einsum("...tj,tjwkb->...wkb", weights, padded))


def pooled_ece(h, sums: dict, methods: Sequence[str], comparisons, per_target: bool = True,
               loto: bool = True) -> dict:
    """{"pooled": {method: {ece_final, ece_overall}}, "per_target": {target: {method: ...}},
    "paired": {comparison key: {ece_<where>: est + wins/losses over targets}}, "reliability":
    {method: {where: diagram}}, "draws": {(comparison key, metric): the paired difference's draws}}
    on the hierarchy ``h`` (``hierarchy.Hierarchy``, one seed)."""
    present = [m for m in methods if any(k[0] == m for k in sums)]
    if not sums or not present:
        return {"pooled": {}, "per_target": {}, "paired": {}, "paired_per_target": {}, "reliability": {}, "draws": {}}
    targets = h.targets
    pads = {m: _padded(h, sums, m) for m in present}
    bw, w0 = h.target_rs.leaf_weights()[:, 0], h.target_rs.point_weights()[0]
    point = {m: _ece(w0, pads[m]) for m in present}
    boot = {m: _ece(bw, pads[m]) for m in present}
    out = {"pooled": {m: {f"ece_{w}": estimate(point[m][i], boot[m][:, i]) for i, w in enumerate(WHERE)}
                      for m in present},
           "per_target": {}, "paired": {}, "paired_per_target": {}, "draws": {},
           "reliability": {m: {w: K.reliability(np.einsum("tj,tjwkb->wkb", w0, pads[m])[i])
                               for i, w in enumerate(WHERE)} for m in present}}
    loo_w = h.target_rs.leaf_weights(slots=len(targets) - 1)[:, 0] if loto and len(targets) >= 3 else None
    tgt = {}
    for ti, t in enumerate(targets):
        rs = h.per_target(ti)
        n = rs.shape[2]
        one, wt = rs.leaf_weights()[:, 0, :, :n], rs.point_weights()[0, :, :n]
        for m in present:
            p = pads[m][ti: ti + 1, :n]
            val, bt = _ece(wt, p), _ece(one, p)
            tgt.setdefault(t, {})[m] = {f"ece_{w}": estimate(val[i], bt[:, i] if n > 1 else None)
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
            out["draws"][(key, f"ece_{w}")] = boot[a][:, i] - boot[b][:, i]
            est = estimate(point[a][i] - point[b][i], out["draws"][(key, f"ece_{w}")])
            res[f"ece_{w}"] = {**est, "wins": float(np.mean(d_t < 0)), "losses": float(np.mean(d_t > 0)),
                               "n_cells": len(targets), "unit": "targets", "better": "lower"}
            if loto:
                res[f"ece_{w}"].update(_loto(h, pads[a], pads[b], i, est, loo_w))
            for t, d in zip(targets, d_t):
                res_t.setdefault(t, {})[f"ece_{w}"] = {"value": float(d), "ci_low": float("nan"),
                                                       "ci_high": float("nan")}
        out["paired"][key] = res
        out["paired_per_target"][key] = res_t
    return out


def _loto(h, pa: np.ndarray, pb: np.ndarray, i: int, full: dict, loo_w: np.ndarray) -> dict:
    """The ECE difference with each target left out (``hierarchy.leave_one_out``): ``full`` its
    estimate on every target, ``loo_w`` the leaf weights of the draws' first T - 1 target slots."""
    from pipeline.evaluation.statistics.hierarchy import leave_one_out  # heavy: pandas

    if loo_w is None:                                    # under 3 targets: no check (leave_one_out says so)
        return leave_one_out(h, full, np.array([]), np.array([]), False)
    T = h.target_rs.shape[1]
    w0 = h.target_rs.point_weights()[0]
    w_loo = np.where(np.eye(T, dtype=bool)[..., None], 0.0, w0[None] * T / (T - 1))   # (T, T, W): row t without t
    points = _ece(w_loo, pa)[:, i] - _ece(w_loo, pb)[:, i]
    return leave_one_out(h, full, points, _ece(loo_w, pa)[:, i] - _ece(loo_w, pb)[:, i], False)
