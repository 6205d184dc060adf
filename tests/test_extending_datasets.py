"""docs/extending.md, "A dataset", checked: a package outside the repository adds a turntable source
(its reader alone) through the ``viewfuse.datasets`` entry point (a dist-info written here, on a
subprocess's PYTHONPATH). The source lists after the built-ins, its [data.<name>] section is read
and checked like every section, the data stage writes its photographs on real-format AVD scans
(tiny synthetic ones, rendered first) in the formats the project's readers read, and its source
enters the data stage's key only when data.source names it."""
from __future__ import annotations

import json

import pytest

from tests.support.outside_package import run_with, write_package
from tests.support.turntable_world import ENTRY_POINTS, PACKAGE, SOURCE_MODULE

PROBE = '''
import json, sys
from pathlib import Path
import viewfuse as vf
from pipeline.infra.config import ConfigError, load_config
from stages.framework.outside import outside_parts
from stages.framework.runner import ensure, stage_key
from stages.framework.registry import STAGES

from tests.support.turntable_world import render_geometry, source_overrides, write_photos

tmp = Path(sys.argv[1]) if len(sys.argv) > 1 else Path.cwd()
out = {"sources": vf.datasets()}
photos = write_photos(tmp / "photos")
cfg = render_geometry(REPO, tmp / "art")
mine = source_overrides(tmp / "art", photos, cfg.stage_dir("data") / "avd", max_view_error_deg=16.0, max_difficulty=5)
cfg2 = load_config(REPO / "configs" / "synthetic.toml", mine)
out["options"] = [type(cfg2.data.options).__name__, cfg2.data.options.train_step_deg]
ensure(cfg2, "data", device="cpu")
data = cfg2.stage_dir("data")
truth = json.loads((data / "truth.json").read_text())
out["objects"] = sorted(truth["objects"])
out["placed"] = sorted(truth["scans"]["Home_001_1"]["instances"])
# the project's readers read what it wrote
from loaders.avd import AVDScan
from loaders.bigbird import BigBirdObject, list_objects
scan = AVDScan(data / "avd", "Home_001_1")
labels = sorted({scan.instance_names[b.instance_id] for img in scan.images.values() for b in img.boxes})
out["labels"] = labels
out["frame_size"] = list(scan.read_image(next(n for n, i in scan.images.items() if i.boxes)).shape)
out["bigbird"] = list_objects(data / "bigbird")
for o in out["bigbird"]:
    BigBirdObject(data / "bigbird" / o).check_calibration((1,))
out["training_views"] = len(list((data / "bigbird" / "mug").glob("NP1_*.jpg")))
out["shown_angles"] = sorted({a for r in truth["scans"]["Home_001_1"]["instances"].values()
                              for a in r["heldout_views_used"]})
# the keys: the outside source's code enters the data stage's key when data.source names it
out["key_parts"] = outside_parts(cfg2, "data")
out["synthetic_parts"] = outside_parts(cfg, "data")
out["options_in_key"] = stage_key(cfg2, STAGES["data"], {})[0] != stage_key(load_config(
    REPO / "configs" / "synthetic.toml", {**mine, "data": {**mine["data"], "outside_turntable": {
        "root": str(photos), "max_view_error_deg": 15.5}}}), STAGES["data"], {})[0]
errors = []
for bad in ({"bogus": 1}, {"root": str(photos), "train_step_deg": 7}):
    try:
        load_config(REPO / "configs" / "synthetic.toml", {**mine, "data": {**mine["data"], "outside_turntable": bad}})
    except ConfigError as e:
        errors.append(str(e))
try:
    load_config(REPO / "configs" / "synthetic.toml", {"data": {"source": "nope"}})
except ConfigError as e:
    errors.append(str(e))
out["errors"] = errors
print("PROBE " + json.dumps(out))
'''


@pytest.fixture(scope="module")
def outside(tmp_path_factory) -> dict:
    from tests.conftest import ROOT

    tmp = tmp_path_factory.mktemp("outside_data")
    site = write_package(tmp / "site", PACKAGE, SOURCE_MODULE, ENTRY_POINTS)
    r = run_with(site, f"REPO = __import__('pathlib').Path({str(ROOT)!r})\n" + PROBE, tmp)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(next(line for line in r.stdout.splitlines() if line.startswith("PROBE "))[6:])


def test_a_dataset_from_an_entry_point_lists_after_the_builtins(outside):
    assert outside["sources"] == ["real", "real_imagery", "synthetic", "outside_turntable"]
    assert outside["options"] == ["TurntableConfig", 30]


def test_its_data_stage_writes_what_the_readers_read(outside):
    assert outside["objects"] == ["bowl", "can", "mug"] == outside["bigbird"]
    assert set(outside["placed"]) <= {"bowl", "can", "mug"} and len(outside["placed"]) >= 2
    assert outside["labels"] == outside["placed"]                  # every box is a placed object's
    assert outside["frame_size"] == [360, 640, 3]                  # frames at the scan's own size
    assert outside["training_views"] == 12                         # 0, 30, ..., 330
    assert outside["shown_angles"] and all(a % 30 == 15 for a in outside["shown_angles"])   # held out only


def test_its_code_and_section_enter_the_data_key_only_when_it_runs(outside):
    assert set(outside["key_parts"]) == {"datasets"}
    assert outside["key_parts"]["datasets"].startswith("outside_turntable=")
    assert outside["synthetic_parts"] == {}
    assert outside["options_in_key"]


def test_its_section_is_checked_and_an_unknown_source_lists_the_registered(outside):
    unknown, step, name = outside["errors"]
    assert "unknown key 'data.outside_turntable.bogus'" in unknown
    assert "'data.outside_turntable.train_step_deg' = 7 must divide 360" in step
    assert "'data.source' = 'nope' is not a registered dataset source (registered: real, real_imagery, " \
           "synthetic, outside_turntable;" in name
