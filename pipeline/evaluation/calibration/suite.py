"""The calibration suite: the engine's intervals on populations with a known answer (``simulate``),
in every design the configs use, and what they cover.

For each design and regime, R replications: the planted method's difference from the baseline
(+``PLANTED``) and ``NULLS`` methods without an effect, on the binary primary metrics and a
continuous one. Each candidate interval is the engine's own computation on the design's leaves,
vectorised over the replications: "bootstrap" is the percentile interval of the engine's shared
draws (``hierarchy.Hierarchy``: its mean statistic is linear in the track values, so the draws are
the draws' leaf weights times the values: exactly ``engine.block``'s draws), "cluster-robust t"
is ``design.t_interval`` (what ``engine.block`` now calls: tests/pipeline/evaluation/calibration
checks that the engine's records equal it). Measured, each with its Wilson 95 % interval over the R
replications (their Monte Carlo error): coverage of the planted difference, the type-I error of one
test at 5 %, the familywise error of the Holm family (the two binary metrics x ``NULLS`` null
comparisons: Holm rejects something iff the smallest p <= 0.05 / m), and the mean half-width over
what the spread of the estimates needs (1.96 x their sd).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.evaluation.calibration.simulate import METRICS, NULLS, PLANTED, Design, Population
from pipeline.evaluation.statistics import design as D
from pipeline.evaluation.statistics.hierarchy import Hierarchy
from pipeline.evaluation.statistics.resampler import interval, wilson_interval

ALPHA = 0.05
BINARY = [k for k, (kind, _) in METRICS.items() if kind == "binary"]

DESIGNS = (
    Design("target 12 x 4 tracks", "synthetic", "target", objects=12, scans=1, tracks=4),
    Design("target 5 x 2 tracks", "smoke", "target", objects=5, scans=1, tracks=2),
    Design("scans 8 > 6 targets", "cluster = scan", "scan", objects=6, scans=8, tracks=2, layout="nested"),
    Design("category 8 x 9, one scan", "real_category (one scan)", "category", objects=72, scans=1, tracks=2,
           categories=8),
    Design("category 8 x 9 in 8 scans", "real_category", "category", objects=9, scans=8, tracks=2,
           layout="nested", categories=8),
    Design("crossed 75 x 15", "real_full", "crossed", objects=75, scans=15, tracks=1),
    Design("crossed 40 x 12", "crossed, 12 scans", "crossed", objects=40, scans=12, tracks=1),
    Design("crossed 12 x 2", "crossed, 2 scans", "crossed", objects=12, scans=2, tracks=2),
    Design("targets 12 x 2 scans", "real (cluster = target)", "target", objects=12, scans=2, tracks=2),
    Design("targets 12 x 8 scans", "real with 8 scans", "target", objects=12, scans=8, tracks=2),
)


@dataclass
class Leaves:
    """A design's leaves as the engine sees them: the template cells, their order in the engine's
    layout (``rows``), the layout and the hierarchy (its draws)."""
    design: Design
    rows: np.ndarray
    layout: D.Layout
    hierarchy: Hierarchy
    wild_boot: int = 2000     # the wild bootstrap-t's draws (``evaluate.bootstrap``)

    @classmethod
    def of(cls, design: Design, n_boot: int, seed: int = 0, wild_boot: int | None = None) -> "Leaves":
        cells = design.cells()
        h = Hierarchy({"run": cells}, n_boot, seed, cluster=design.cluster)
        pos, layout = h.layout()
        idx = cells.assign(row=np.arange(len(cells), dtype=float))
        padded = h.pad([idx], "row")
        return cls(design, padded.ravel()[pos].astype(np.int64), layout, h, wild_boot or n_boot)

    def cells(self):
        return self.design.cells().iloc[self.rows].reset_index(drop=True)

    def draw_weights(self) -> np.ndarray:
        """(B, N): each bootstrap draw's weight on each leaf (the engine's shared draws)."""
        rs, pos = self.hierarchy.rs, self.hierarchy.layout()[0]
        lw = rs.leaf_weights()
        return lw.reshape(len(lw), -1)[:, pos]


def bootstrap(leaves: Leaves, d: np.ndarray) -> dict:
    """The former engine interval: the percentile interval of the shared draws, its p from the draws."""
    draws = d @ leaves.draw_weights().T                                            # (R, B)
    value = d @ leaves.layout.weights
    lo, hi = interval(draws, axis=-1)
    B = draws.shape[1]
    p = np.minimum(1.0, 2 * np.minimum(1 + (draws <= 0).sum(-1), 1 + (draws >= 0).sum(-1)) / (B + 1))
    return {"value": value, "ci_low": np.minimum(lo, value), "ci_high": np.maximum(hi, value), "p": p,
            "withheld": None}


def cluster_robust(leaves: Leaves, d: np.ndarray) -> dict:
    """The previous engine interval: the cluster-robust t against t_df."""
    return D.t_interval(d, leaves.layout)


def wild_t(leaves: Leaves, d: np.ndarray) -> dict:
    """The engine's interval: the same t against its wild cluster bootstrap (``statistics.wild``)."""
    return D.t_interval(d, leaves.layout, n_boot=leaves.wild_boot, seed=leaves.hierarchy.seed)


CANDIDATES: dict[str, Callable[[Leaves, np.ndarray], dict]] = {"bootstrap": bootstrap,
                                                                D.T_INTERVAL: cluster_robust,
                                                                D.INTERVAL: wild_t}


def share(k: int, n: int) -> dict:
    lo, hi = wilson_interval(k, n)
    return {"share": k / n, "lo": lo, "hi": hi, "k": int(k), "n": int(n)}


def run(design: Design, regime: str, R: int, seed: int, candidates: Sequence[str] = tuple(CANDIDATES),
        n_boot: int = 2000, leaves: Leaves | None = None, wild_boot: int | None = None) -> dict[str, dict]:
    """{candidate: {"coverage": {metric: share}, "type1": share, "fwer": share, "width": {metric:
    ratio}, "withheld": reason or None}} of R replications of ``design`` in ``regime`` (``n_boot``:
    the bootstrap candidate's draws; ``wild_boot``: the wild bootstrap's, default the same)."""
    leaves = leaves or Leaves.of(design, n_boot, wild_boot=wild_boot)
    pop = Population(design, leaves.cells(), regime, np.random.default_rng(seed))
    out = {c: {"coverage": {}, "width": {}, "type1": [0, 0], "p_min": np.full(R, np.inf), "withheld": None}
           for c in candidates}
    for metric in METRICS:
        vals, truth = pop.draw(metric, R)
        for c in candidates:
            fn, o = CANDIDATES[c], out[c]
            res = fn(leaves, vals["planted"] - vals["base"])
            o["withheld"] = res["withheld"]
            if res["withheld"]:
                continue
            o["coverage"][metric] = share(int(((res["ci_low"] <= truth) & (truth <= res["ci_high"])).sum()), R)
            need = 1.96 * np.std(res["value"] - truth)
            o["width"][metric] = float(np.mean(res["ci_high"] - res["ci_low"]) / 2 / need) if need > 0 else np.nan
            for i in range(NULLS):
                r0 = fn(leaves, vals[f"null{i}"] - vals["base"])
                if i == 0:   # one test a replication: the type-I share's replications are independent
                    o["type1"][0] += int((r0["p"] <= ALPHA).sum())
                    o["type1"][1] += R
                if metric in BINARY:
                    o["p_min"] = np.minimum(o["p_min"], r0["p"])
    m = len(BINARY) * NULLS
    for o in out.values():
        k, n = o.pop("type1")
        p_min = o.pop("p_min")
        o["type1"] = share(k, n) if n else None
        o["fwer"] = None if o["withheld"] else share(int((p_min <= ALPHA / m).sum()), R)
        o["family"] = m
    return out


def suite(designs: Sequence[Design] = DESIGNS, R: int = 1000, seed: int = 0,
          candidates: Sequence[str] = tuple(CANDIDATES), n_boot: int = 2000) -> list[dict]:
    """Every design in each of its regimes: one row per (design, regime, candidate)."""
    rows = []
    for i, d in enumerate(designs):
        leaves = Leaves.of(d, n_boot)
        for j, regime in enumerate(d.regimes):
            res = run(d, regime, R, seed + 1000 * i + j, candidates, n_boot, leaves)
            for c, r in res.items():
                rows.append({"design": d.name, "stands_for": d.stands_for, "cluster": d.cluster,
                             "levels": leaves.layout.levels(), "regime": regime, "candidate": c, "R": R, **r})
    return rows


def in_band(s: Mapping, band: tuple[float, float], z: float) -> bool:
    """Whether a measured share is consistent with a true share inside ``band``: its Wilson interval
    at ``z`` (the Monte Carlo error of R replications) reaches the band."""
    lo, hi = wilson_interval(s["k"], s["n"], z)
    return hi >= band[0] and lo <= band[1]


PLANTED_DIFF = PLANTED
