"""Populations with a known answer, for the calibration suite (``suite``): every design the configs
use, their track values drawn for many replications at once.

A design is objects (targets), scans, categories and tracks, laid out as a config's population is:
"crossed" (every object seen in every scan: real_full), "nested" (each object in one scan), with
categories over the objects (real_category). A track's value for method m comes from one latent
score: eta = mu + delta_m + (object + scan + category + object×scan + track effects shared by the
methods) + (the same levels' effects of method m alone); a binary metric (correct ratio,
confident-error rate) is a Bernoulli draw of logistic(eta), a continuous one is eta itself. The
method-specific effects are what a paired difference varies with; the regime sets their sizes:
"track" (track noise dominates, as on real_full: 40-50 % of a target mean's variance) and "cluster"
(object, scan and category effects dominate). The answer is known: the methods without a planted
effect have the baseline's distribution (a difference of exactly 0), and the planted method's
latent shift is solved so that its expected difference is exactly ``PLANTED`` (Gauss-Hermite).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.optimize import brentq
from scipy.special import expit

PLANTED = 0.05
NULLS = 4          # methods without an effect, each compared with the baseline: a family of 4 x 2 primary metrics
# metric -> (kind, mu): the latent level that puts the baseline near what the configs see
METRICS = {"correct_final": ("binary", 1.0), "confident_error_final": ("binary", -2.2),
           "prob_truth_final": ("continuous", 0.6)}
LEVELS = ("object", "scan", "category", "object_scan", "track")
SHARED_SD = {"object": 1.0, "scan": 0.5, "category": 0.5, "object_scan": 0.3, "track": 0.5}
REGIMES = {"track": {"object": 0.15, "scan": 0.15, "category": 0.15, "object_scan": 0.1, "track": 1.0},
           "cluster": {"object": 0.6, "scan": 0.6, "category": 0.6, "object_scan": 0.2, "track": 0.3}}
CONTINUOUS_SCALE = 0.1   # a continuous metric's effects: the latent sizes times this


@dataclass(frozen=True)
class Design:
    """One population shape: ``objects`` (per scan where ``layout`` is "nested"), ``scans``,
    ``tracks`` per (object, scan), ``categories`` (0: none) and the clustering the config names."""
    name: str
    stands_for: str
    cluster: str
    objects: int
    scans: int
    tracks: int
    layout: str = "crossed"
    categories: int = 0
    regimes: tuple[str, ...] = field(default=("track", "cluster"))

    def cells(self) -> pd.DataFrame:
        """The population's (target, track, scan, category) rows with each track's object, scan
        and category index (one method, one setting: the suite's template)."""
        rows = []
        n_obj = self.objects * (self.scans if self.layout == "nested" else 1)
        for o in range(n_obj):
            cat = o % self.categories if self.categories else 0
            scans = [o // self.objects] if self.layout == "nested" else range(self.scans)
            for s in scans:
                for j in range(self.tracks):
                    name = f"c{cat}__f{o}" if self.categories else f"o{o:03d}"
                    rows.append({"target": name, "track": s * self.tracks + j, "scan": f"S{s:02d}",
                                 "category": f"c{cat}", "setting": "x", "method": "m", "obj": o, "scan_i": s,
                                 "cat_i": cat})
        return pd.DataFrame(rows)


def _gauss_mean(mu: float, sd: float) -> float:
    x, w = np.polynomial.hermite_e.hermegauss(80)
    return float((w * expit(mu + sd * x)).sum() / w.sum())


def planted_shift(mu: float, sd: float, diff: float = PLANTED) -> float:
    """The latent shift whose expected Bernoulli difference, over effects of total sd ``sd``, is ``diff``."""
    base = _gauss_mean(mu, sd)
    return brentq(lambda d: _gauss_mean(mu + d, sd) - base - diff, -10, 10, xtol=1e-12)


def latent_sd(design: Design, regime: str) -> float:
    """The total latent sd of one method's track score (shared and method-specific effects)."""
    keep = [k for k in LEVELS if (k != "category" or design.categories) and (k != "scan" or design.scans > 1)]
    return float(np.sqrt(sum(SHARED_SD[k] ** 2 + REGIMES[regime][k] ** 2 for k in keep)))


class Population:
    """R replications of ``design``'s track values for every method, in the order of ``leaves``
    (the design's track rows: obj, scan_i, cat_i), drawn with ``rng``."""

    def __init__(self, design: Design, leaves: pd.DataFrame, regime: str, rng: np.random.Generator):
        self.design, self.regime, self.rng = design, regime, rng
        self.obj = leaves["obj"].to_numpy()
        self.scan = leaves["scan_i"].to_numpy()
        self.cat = leaves["cat_i"].to_numpy()
        self.n_obj, self.n_scan = int(self.obj.max()) + 1, int(self.scan.max()) + 1
        self.n_cat = int(self.cat.max()) + 1

    def _effects(self, R: int, sds: dict, scale: float) -> np.ndarray:
        rng, N = self.rng, len(self.obj)
        out = scale * sds["object"] * rng.standard_normal((R, self.n_obj))[:, self.obj]
        if self.n_scan > 1:   # one scan is fixed, not drawn: the answer is that scan's
            out += scale * sds["scan"] * rng.standard_normal((R, self.n_scan))[:, self.scan]
        if self.design.categories:
            out += scale * sds["category"] * rng.standard_normal((R, self.n_cat))[:, self.cat]
        os_ = self.obj * self.n_scan + self.scan
        out += scale * sds["object_scan"] * rng.standard_normal((R, self.n_obj * self.n_scan))[:, os_]
        out += scale * sds["track"] * rng.standard_normal((R, N))
        return out

    def draw(self, metric: str, R: int) -> tuple[dict[str, np.ndarray], float]:
        """({method: (R, N) track values}, the planted method's true difference): methods "base",
        "planted" and "null0".."null{NULLS-1}"."""
        kind, mu = METRICS[metric]
        scale = CONTINUOUS_SCALE if kind == "continuous" else 1.0
        shared = self._effects(R, SHARED_SD, scale)
        sd = latent_sd(self.design, self.regime)
        shift = PLANTED if kind == "continuous" else planted_shift(mu, sd)
        out = {}
        for m, delta in [("base", 0.0), ("planted", shift)] + [(f"null{i}", 0.0) for i in range(NULLS)]:
            eta = mu + delta + shared + self._effects(R, REGIMES[self.regime], scale)
            out[m] = eta if kind == "continuous" else (self.rng.random(eta.shape) < expit(eta)).astype(float)
        return out, PLANTED
