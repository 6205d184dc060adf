"""A dataset source from a package outside the repository (its ``viewfuse.datasets`` entry point,
docs/extending.md "A dataset") through a small chain: data -> classifier -> features -> models ->
evaluate, with configs/real.toml's network (EfficientNet-Lite0, the installed package's ImageNet
weights) on a turntable folder drawn here (3 objects x 12 angles of 64 px) shown in tiny synthetic
AVD scans. The outside objects are the classes, the modelled candidates and the evaluated targets,
and the cost model estimated the source's frames before any stage ran."""
from __future__ import annotations

import json

import pytest

from pipeline.infra.config import merge
from tests.stages.test_real_imagery_chain import SMALL
from tests.support.outside_package import run_with, write_package
from tests.support.turntable_world import COLOURS, ENTRY_POINTS, PACKAGE, SCAN, SOURCE_MODULE

pytestmark = pytest.mark.slow  # five real stages (make test-fast skips it)

# configs/real.toml's chain at SMALL (tests/stages/test_real_imagery_chain.py) on the outside source:
# photographs every 30 degrees, every other one trains (6 views a class), the others are the frames
CHAIN = merge({k: v for k, v in SMALL.items() if k not in ("data", "report")}, {
    "classifier": {"input_size": 64},
    "features": {"max_difficulty": 5},
    "models": {"min_views": 4},
    "evaluate": {"max_difficulty": 5, "experiments": ["biased", "randomized"], "attribution": False},
    "plan": {"enabled": False},
})

PROBE = '''
import json, sys
from pathlib import Path
import viewfuse as vf
from pipeline.infra import cost
from pipeline.infra.config import load_config, merge
from stages.framework.runner import ensure
from tests.support.turntable_world import render_geometry, source_overrides, write_photos

tmp = Path.cwd()
photos = write_photos(tmp / "photos", step_deg=30)
geo = render_geometry(REPO, tmp / "art")
over = merge(source_overrides(tmp / "art", photos, geo.stage_dir("data") / "avd", train_step_deg=60,
                              max_view_error_deg=30.0, max_difficulty=5), CHAIN)
cfg = load_config(REPO / "configs" / "real.toml", merge(over, {"run": {"device": "cpu"}}))
work = cost.source_work(cfg)
out = {"source": cfg.data.source, "arch": cfg.classifier.arch, "weights": cfg.classifier.weights,
       "work": [work.training_views, work.test_crops],
       "features_estimate_s": cost.estimate(cfg, "features").seconds}
keys = {}
ensure(cfg, "evaluate", device="cpu", _keys=keys)
out["truth"] = json.loads((cfg.stage_dir("data") / "truth.json").read_text())
out["models"] = json.loads((cfg.stage_dir("models") / "index.json").read_text())["classes"]
out["features"] = json.loads((cfg.stage_dir("features") / "manifest.json").read_text())["extra"]
out["population"] = json.loads((cfg.stage_dir("evaluate") / "summary.json").read_text())["population"]
print("PROBE " + json.dumps(out))
'''


@pytest.fixture(scope="module")
def chain(tmp_path_factory) -> dict:
    from tests.conftest import ROOT

    tmp = tmp_path_factory.mktemp("outside_chain")
    site = write_package(tmp / "site", PACKAGE, SOURCE_MODULE, ENTRY_POINTS)
    head = f"REPO = __import__('pathlib').Path({str(ROOT)!r})\nCHAIN = {CHAIN!r}\n"
    r = run_with(site, head + PROBE, tmp)
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(next(line for line in r.stdout.splitlines() if line.startswith("PROBE "))[6:])


def test_the_chain_runs_on_the_outside_source_with_the_real_imagery_network(chain):
    assert chain["source"] == "outside_turntable"
    assert (chain["arch"], chain["weights"]) == ("efficientnet_lite0", "imagenet")
    objects = sorted(COLOURS)
    assert sorted(chain["truth"]["objects"]) == objects
    for rec in chain["truth"]["objects"].values():
        assert rec["training_angles"] == [0, 60, 120, 180, 240, 300]
        assert rec["heldout_angles"] == [30, 90, 150, 210, 270, 330]
    assert sorted(chain["models"]) == objects                  # the outside objects are the modelled classes
    assert chain["features"]["bigbird_crops"] == 3 * 6
    assert chain["features"]["avd_crops"] > 0


def test_the_evaluate_summary_has_cells_for_the_sources_objects(chain):
    pop = chain["population"]
    placed = set(chain["truth"]["scans"][SCAN]["instances"])
    assert len(placed) >= 2 and placed <= set(COLOURS)
    assert set(pop["targets"]) <= placed and len(pop["targets"]) >= 2
    cells = pop["cells"]
    assert {c["target"] for c in cells} == set(pop["targets"])
    assert {c["experiment"] for c in cells} == {"biased", "randomized"}
    for c in cells:
        assert {"with_uncertainty", "model_based", "simple_bayes"} <= set(c["values"])
    for t, cands in pop["candidates"].items():
        assert t in cands and set(cands) <= set(COLOURS)     # candidates are the source's objects


def test_the_cost_model_estimated_the_sources_frames_before_the_run(chain):
    views, crops = chain["work"]
    assert views is None                        # the reader decides how many photographs train: not estimated
    assert crops > 0 and chain["features_estimate_s"] > 0
