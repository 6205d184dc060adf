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

MODULE = '''
import re
import cv2
import numpy as np
import viewfuse as vf

NAME = re.compile(r"([a-z]+)_(\\d{3})\\.png")


class Folder(vf.TurntableSource):       # no decorator: the entry point names the class
    name = "outside_turntable"

    def read(self, cfg, skips):
        out = {}
        for p in sorted(self.path(cfg, "root").glob("*.png")):
            m = NAME.fullmatch(p.name)
            rgb = np.ascontiguousarray(cv2.imread(str(p))[:, :, ::-1])
            out.setdefault(m[1], {})[int(m[2])] = (rgb, rgb.max(axis=2) > 16)
        return out
'''

PROBE = '''
import json, sys
from pathlib import Path
import cv2
import numpy as np
import viewfuse as vf
from pipeline.infra.config import ConfigError, load_config
from stages.framework.outside import outside_parts
from stages.framework.runner import ensure, stage_key
from stages.framework.registry import STAGES

tmp = Path(sys.argv[1]) if len(sys.argv) > 1 else Path.cwd()
out = {"sources": vf.datasets()}
photos = tmp / "photos"
photos.mkdir()
for name, colour in {"mug": (200, 60, 40), "bowl": (40, 160, 200), "can": (90, 200, 70)}.items():
    for a in range(0, 360, 15):
        img = np.zeros((64, 64, 3), np.uint8)
        cv2.rectangle(img, (16, 10), (48, 56), colour, -1)
        cv2.circle(img, (int(32 + 12 * np.sin(np.radians(a))), 30), 5, (255, 255, 255), -1)
        cv2.imwrite(str(photos / f"{name}_{a:03d}.png"), img)
root = Path.cwd().resolve()
syn = {"run": {"artifacts": str(tmp / "art"), "name": "geometry"}, "evaluate": {"n_candidates": 3},
       "data": {"scans": ["Home_001_1"], "synthetic": {
           "instances": ["red_bull", "pringles_bbq", "pepto_bismol"], "angle_step_deg": 120, "bigbird_width": 64,
           "bigbird_height": 64, "room_size_m": [2.4, 2.4], "grid_step_m": 0.5,
           "distractors": 1, "occluders": 1, "workers": 1}}}
cfg = load_config(REPO / "configs" / "synthetic.toml", syn)
ensure(cfg, "data", device="cpu")
mine = {"run": {"artifacts": str(tmp / "art"), "name": "photos"}, "evaluate": {"n_candidates": 3},
        "data": {"source": "outside_turntable", "scans": ["Home_001_1"],
                 "avd_root": str(cfg.stage_dir("data") / "avd"),
                 "outside_turntable": {"root": str(photos), "max_view_error_deg": 16.0, "max_difficulty": 5}}}
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
    site = write_package(tmp / "site", "vf_outside_data", MODULE,
                         {"viewfuse.datasets": {"outside_turntable": "vf_outside_data:Folder"}})
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
