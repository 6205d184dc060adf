"""pipeline/infra/cost.py against finished runs: every stage of every run recorded below is
estimated within a factor of two of what its manifest recorded (tests/support/estimates.py: estimate
<= 2 x wall, and >= CPU s / cores / 2, so a loaded machine's inflated wall seconds cannot hide an
underestimate). The figures are the manifests' ``seconds`` and ``cpu_seconds``; the config is the
file named with the overrides that run's manifest (``parts.sections``) differs from it by.
tests/bench/bench_chains.py applies the same check to the chains it runs, on the machine at hand
(machine-dependent, so in ``make bench``: a faster machine runs a small stage in under half the estimate).

Recorded on the 2-core AMD EPYC shared with 7 other sessions (load 4-20, so the wall seconds are
inflated; CPU seconds are what the lower bound reads), December 7 2026:
- real_category: branch ``likelihood`` (head d7727f3), ``viewfuse evaluate --config
  configs/real_category.toml`` with the overrides below (evaluate code hash 86e09fa7).
- real / real_black / real clutter: branch ``crops`` (head 326bfa0), ``viewfuse report --config
  configs/real.toml`` (base: with data.real_imagery.background = "black", the default then),
  ``configs/real_black.toml``, ``configs/real.toml``.
- smoke at 4 and at 40 steps: branch ``estimates`` (e3bad78), ``viewfuse evaluate --config
  configs/smoke.toml --set run.artifacts=artifacts/kk --set run.name=k40 --set
  evaluate.track_length=40`` (then run.name=k4 without the track length), one process for the chain.
- The real runs above predate ``evaluate.fit_spaces``: their overrides turn it off (no fit-only bank).
- real with its fit-only banks (log, logit, clr): branch ``fitbanks``, ``viewfuse report --config
  configs/real.toml`` from an empty run folder, nice 5, load 7-9.
- synthetic (the default, the main job) and real_full: main at 00f475a (every branch merged),
  ``make features models evaluate ARGS="--progress off"`` then ``viewfuse report``, and ``viewfuse
  evaluate --config configs/real_full.toml --progress off``, both at nice 10 beside the test suite.
"""
from __future__ import annotations

import json

import pytest

from pipeline.infra import cost
from pipeline.infra.config import load_config
from tests.conftest import ROOT
from tests.support.estimates import misfit

CORES = 2
RUNS = json.loads("""{
 "real_category": {"config": "real_category.toml",
   "overrides": {"evaluate": {"experiments": ["randomized"], "ablations": [], "attribution": false,
                              "likelihood_tail": "student_t", "fit_spaces": []},
                 "plan": {"enabled": false},
                 "models": {"dirichlet": {"max_iter": 1}, "noise_bounds": [1e-6, 100.0],
                            "noise_prior": [0.001, 10.0], "score_space": "log"}},
   "stages": {"data": [78.584, 52.229], "classifier": [9.696, 5.634], "features": [1073.423, 159.925],
              "models": [68.825, 18.601], "evaluate": [620.273, 159.449]}},
 "real_base": {"config": "real.toml", "overrides": {"data": {"real_imagery": {"background": "black"}},
                                                    "evaluate": {"fit_spaces": []}},
   "stages": {"data": [45.605, 14.821], "classifier": [16.208, 4.437], "features": [293.1, 45.826],
              "models": [38.035, 7.357], "evaluate": [681.839, 71.536], "report": [622.888, 39.721]}},
 "real_black": {"config": "real_black.toml", "overrides": {"evaluate": {"fit_spaces": []}},
   "stages": {"data": [215.188, 20.87], "classifier": [47.492, 4.569], "features": [783.992, 54.105],
              "models": [106.704, 5.838], "evaluate": [1086.221, 79.295], "report": [553.67, 42.112]}},
 "real_clutter": {"config": "real.toml", "overrides": {"evaluate": {"fit_spaces": []}},
   "stages": {"data": [346.297, 22.286], "classifier": [80.316, 5.908], "features": [792.081, 53.754],
              "models": [78.525, 4.788], "evaluate": [753.615, 81.999], "report": [191.344, 47.496]}},
 "real_fit_banks": {"config": "real.toml", "overrides": {},
   "stages": {"data": [98.203, 17.329], "classifier": [15.302, 2.458], "features": [186.524, 43.647],
              "models": [25.229, 6.034], "evaluate": [151.791, 68.534], "report": [72.0, 32.7]}},
 "smoke_40_steps": {"config": "smoke.toml", "overrides": {"evaluate": {"track_length": 40}},
   "stages": {"data": [16.755, 14.653], "classifier": [16.063, 12.71], "features": [13.991, 11.994],
              "models": [1.897, 1.593], "evaluate": [32.673, 27.144], "report": [74.199, 40.356]}},
 "smoke_4_steps": {"config": "smoke.toml", "overrides": {}, "stages": {"evaluate": [29.443, 25.925]}},
 "synthetic": {"config": "synthetic.toml", "overrides": {},
   "stages": {"data": [267.78, 97.979], "classifier": [1253.949, 511.466], "features": [79.761, 90.345],
              "models": [13.18, 21.734], "evaluate": [80.2, 119.355], "report": [38.294, 37.727]}},
 "real_full": {"config": "real_full.toml", "overrides": {"evaluate": {"fit_spaces": []}},
   "stages": {"data": [1360.73, 210.426], "classifier": [12.811, 3.068], "features": [1927.804, 518.851],
              "models": [33.749, 31.878], "evaluate": [274.116, 280.33], "report": [31.619, 30.882]}}
}""")

CASES = [(run, stage) for run, r in RUNS.items() for stage in r["stages"]]


@pytest.mark.parametrize("run, stage", CASES)
def test_the_estimate_is_within_a_factor_of_two_of_the_recorded_run(run, stage):
    r = RUNS[run]
    cfg = load_config(ROOT / "configs" / r["config"], r["overrides"])
    seconds, cpu = r["stages"][stage]
    problem = misfit(stage, cost.estimate(cfg, stage).seconds, seconds, cpu, CORES)
    assert problem is None, f"{run}: {problem}"


def test_the_real_category_estimate_counts_its_72_fold_classes_and_their_components():
    """The misses the record showed: 12 classes (COIL's objects) and no fit per component."""
    cfg = load_config(ROOT / "configs" / "real_category.toml")
    terms = {t.what.split(" (")[0]: t for t in cost.models_terms(cfg)}
    assert terms["the GP fits"].what.startswith("the GP fits (72 classes x about 12 components x 128 views")
    assert "72 classes at 1000 entries + 288 set fits" in terms["the Dirichlet fits"].what   # the provider's own
    parts = {t.what.split(" (")[0] for t in cost.evaluate_terms(cfg)}
    assert {"the cells' own work", "the test-domain fit", "the population statistics"} <= parts
