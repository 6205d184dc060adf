"""The paper's §5.3 statements about its Figs. 3 and 5, checked on simulated realizations.

Each claim is the paper's statement (declared once, with its section, in
``pipeline.evaluation.metrics.paper.SIMULATION_CLAIMS``), one statistic computed
from the realizations, its 95 % CI over realizations, a threshold and a direction. The verdict is
computed from the statistic (``holds``); ``ci_side`` says whether the whole interval agrees
("holds" / "fails") or straddles the threshold ("spans"), so a verdict that one more realization
could flip is visible as such.

Where the paper gives a number (steps, 20 %, 0.2, 0.33) the threshold is the paper's. Where it
speaks qualitatively, the reading is stated in ``statistic`` and the threshold is ours:

* "Simple Bayes performs poorly ... around step 15": its 20th percentile of P(truth) at that step
  is below 0.2, the level the first claim calls a low P(truth).
* "accumulates evidence gracefully" (localization bias): at most 5 % of realizations (one in 20)
  have a confident error (``metrics.confident_errors``: max P >= ``confident_threshold`` on a
  wrong class) at any step.
* "Simple Bayes performs well" (localization bias): its final-step correct ratio is at least 0.9.

Pure functions over posteriors (R, K, C) per method; the ``simulate`` stage and the regime sweep
(``pipeline.evaluation.simulation.sweep``) call ``evaluate_claims``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
from scipy import stats

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.metrics.labels import MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY
from pipeline.evaluation.metrics.paper import SIMULATION_CLAIMS
from pipeline.evaluation.statistics.engine import over_members as within
from pipeline.evaluation.statistics.records import outcome
from pipeline.evaluation.statistics.resampler import wilson_interval

LEVEL = 0.95
OPS = {">": np.greater, "<": np.less, ">=": np.greater_equal, "<=": np.less_equal}


@dataclass(frozen=True)
class ClaimParams:
    step: int                   # the paper's "step 15" (0-based step index of the track)
    confident_threshold: float  # confident error: max P >= this on a wrong class
    n_boot: int = 2000          # bootstrap resamples for mean differences
    seed: int = 0


@dataclass(frozen=True)
class Estimate:
    value: float
    ci_low: float
    ci_high: float
    n: int                      # realizations the statistic is computed over
    detail: str = ""            # the numbers behind a difference or a share, for people


@dataclass(frozen=True)
class ClaimSpec:
    key: str
    scenario: str
    statement: str              # the paper's wording, quoted from its §5.3
    statistic: str              # what is computed, in words ("{step}" filled in)
    op: str                     # value <op> threshold = holds
    threshold: float
    compute: Callable[[Mapping[str, np.ndarray], int, ClaimParams], Estimate]
    section: str = "§5.3"


# -- statistics with CIs over realizations ----------------------------------------------------------
def share(flags: np.ndarray) -> Estimate:
    """Share of True over realizations with its Wilson interval."""
    f = np.asarray(flags, bool).ravel()
    lo, hi = wilson_interval(float(f.sum()), len(f))
    return Estimate(float(f.mean()), lo, hi, len(f), f"{int(f.sum())} of {len(f)}")


def quantile(x: np.ndarray, q: float, level: float = LEVEL) -> Estimate:
    """The q-quantile (linear interpolation, as ``numpy.percentile``) with the distribution-free
    order-statistic interval: [x_(l), x_(u)] with l, u the binomial(n, q) quantiles, which covers
    the true quantile with probability >= ``level`` whatever the distribution."""
    x = np.sort(np.asarray(x, float).ravel())
    n = len(x)
    v = float(np.percentile(x, 100 * q))
    a = (1 - level) / 2
    lo_i = int(np.clip(stats.binom.ppf(a, n, q), 1, n)) - 1
    hi_i = int(np.clip(stats.binom.ppf(1 - a, n, q) + 1, 1, n)) - 1
    return Estimate(v, min(float(x[lo_i]), v), max(float(x[hi_i]), v), n)


def paired_mean_difference(a: np.ndarray, b: np.ndarray, p: ClaimParams) -> Estimate:
    """Mean over realizations of a - b (one value per realization), seeded bootstrap CI."""
    d = np.asarray(a, float) - np.asarray(b, float)
    e = within(d, p.n_boot, p.seed)
    return Estimate(e["value"], e["ci_low"], e["ci_high"], len(d),
                    f"{float(np.mean(a)):.3f} vs {float(np.mean(b)):.3f}")


def p_truth(posts: Mapping[str, np.ndarray], method: str, truth: int) -> np.ndarray:
    return M.prob_truth(posts[method], truth)                       # (R, K)


def _log(p: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.log(np.asarray(p, float))


# -- the claims ---------------------------------------------------------------------------------------
def _mb_low(posts, truth, p):
    return share(p_truth(posts, MODEL_BASED, truth)[:, p.step] < 0.2)


def _ours_p20(posts, truth, p):
    return quantile(p_truth(posts, WITH_UNCERTAINTY, truth)[:, p.step], 0.2)


def _ours_more_correct(posts, truth, p):
    ok = {m: M.correct(posts[m], truth).mean(axis=1) for m in (WITH_UNCERTAINTY, MODEL_BASED)}
    return paired_mean_difference(ok[WITH_UNCERTAINTY], ok[MODEL_BASED], p)


def _sb_poor(posts, truth, p):
    return quantile(p_truth(posts, SIMPLE_BAYES, truth)[:, p.step], 0.2)


def _ours_graceful(posts, truth, p):
    err = M.confident_errors(_log(posts[WITH_UNCERTAINTY]), truth, p.confident_threshold)
    return share(err.any(axis=1))


def _sb_well(posts, truth, p):
    return share(M.correct(posts[SIMPLE_BAYES], truth)[:, -1])


MU, LB = "model_uncertainty", "localization_bias"
COMPUTE = {"mb_low_at_step": _mb_low, "ours_p20_at_step": _ours_p20, "ours_more_correct": _ours_more_correct,
           "sb_poor_at_inverse": _sb_poor, "ours_graceful_bias": _ours_graceful, "sb_well_bias": _sb_well}
# The statements, thresholds and sections are declared once, with the scorecard's claims
# (pipeline.evaluation.metrics.paper); here each gets the statistic that tests it.
CLAIMS: tuple[ClaimSpec, ...] = tuple(
    ClaimSpec(c.key, c.scenario, c.statement, c.statistic, c.op, c.threshold, COMPUTE[c.key], c.section)
    for c in SIMULATION_CLAIMS)
BY_KEY = {c.key: c for c in CLAIMS}


def holds(value: float, op: str, threshold: float) -> bool:
    """The verdict: does ``value <op> threshold``? (NaN never holds.)"""
    return bool(np.isfinite(value) and OPS[op](value, threshold))


def ci_side(lo: float, hi: float, op: str, threshold: float) -> str:
    """"holds" / "fails" when the whole 95 % interval is on one side of the threshold, else "spans":
    the one outcome rule (``records.outcome``) applied to the interval minus the threshold, with the
    claimed side (``op``) as the good one. A non-finite end spans."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "spans"
    res = outcome(float(lo) - threshold, float(hi) - threshold, op in (">", ">="))
    return {"better": "holds", "worse": "fails"}.get(res, "spans")


def evaluate_claim(spec: ClaimSpec, posts: Mapping[str, np.ndarray], truth: int, p: ClaimParams) -> dict:
    """One claim on one scenario's posteriors {method: (R, K, C)}: a JSON-ready record."""
    K = next(iter(posts.values())).shape[1]
    if not 0 <= p.step < K:
        raise ValueError(f"claims: step {p.step} is outside the track's {K} steps (simulate.claim_step)")
    e = spec.compute(posts, truth, p)
    return {
        "key": spec.key, "scenario": spec.scenario, "statement": spec.statement, "section": spec.section,
        "statistic": spec.statistic.format(step=p.step, conf=p.confident_threshold),
        "op": spec.op, "threshold": spec.threshold,
        "value": e.value, "ci_low": e.ci_low, "ci_high": e.ci_high, "n": e.n, "detail": e.detail,
        "holds": holds(e.value, spec.op, spec.threshold),
        "ci_side": ci_side(e.ci_low, e.ci_high, spec.op, spec.threshold),
    }


def evaluate_claims(posteriors: Mapping[str, Mapping[str, np.ndarray]], truth: int, p: ClaimParams,
                    keys: tuple[str, ...] | None = None) -> list[dict]:
    """Every claim whose scenario is in ``posteriors`` ({scenario: {method: (R, K, C)}})."""
    out = []
    for spec in CLAIMS:
        if (keys is None or spec.key in keys) and spec.scenario in posteriors:
            out.append(evaluate_claim(spec, posteriors[spec.scenario], truth, p))
    return out


def verdict_word(rec: Mapping) -> str:
    """"holds" / "does not hold", with "(CI spans the threshold)" when the interval straddles it."""
    w = "holds" if rec["holds"] else "does not hold"
    return w + (" (95 % CI spans the threshold)" if rec["ci_side"] == "spans" else "")


def confident_errors_by_step(posts: Mapping[str, np.ndarray], truth: int, threshold: float) -> dict[str, dict]:
    """Per method and step: the confident-error rate over realizations (``metrics.confident_errors``,
    the evaluate stage's definition) with its Wilson 95 % interval."""
    out = {}
    for m, p in posts.items():
        err = M.confident_errors(_log(p), truth, threshold)                 # (R, K)
        R = err.shape[0]
        ci = [wilson_interval(float(k), R) for k in err.sum(axis=0)]
        out[m] = {"rate": err.mean(axis=0).tolist(), "ci_low": [c[0] for c in ci], "ci_high": [c[1] for c in ci],
                  "overall": float(err.mean()), "final": float(err[:, -1].mean()), "realizations": int(R)}
    return out
