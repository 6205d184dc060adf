"""Stage ``data`` through the runner: outputs, manifest, skip-on-rerun, workers, real-data checks."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from loaders.avd import AVDScan
from loaders.bigbird import BigBirdObject, list_objects
from loaders.errors import BadInputError
from loaders.synthetic.avd_writer import plan_scan
from loaders.synthetic.scene import scan_instances
from pipeline.infra.config import merge
from stages.data import data_roots, extra_key
from stages.framework.runner import ensure, read_manifest

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

TINY = {"data": {"synthetic": {
    "bigbird_width": 128, "bigbird_height": 96, "angle_step_deg": 120, "avd_width": 96, "avd_height": 54,
    "room_size_m": [2.4, 2.1], "grid_step_m": 0.6, "distractors": 2, "workers": 1}}}


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != "manifest.json"}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from pipeline.infra.config import load_config
    from tests.conftest import DEFAULT_CONFIG

    art = tmp_path_factory.mktemp("art")
    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {"artifacts": str(art)}}))
    ensure(cfg, "data")
    return cfg


def test_stage_writes_both_roots_truth_and_manifest(built):
    cfg = built
    out = cfg.stage_dir("data")
    m = read_manifest(cfg, "data")
    assert m["stage"] == "data" and "synthetic" in m["summary"]
    n = len(cfg.data.synthetic.instances)
    assert m["extra"]["bigbird_views"] == n * 3 and m["extra"]["avd_images"] % 12 == 0
    bb, avd = data_roots(cfg)
    assert (bb, avd) == (out / "bigbird", out / "avd")
    assert list_objects(bb) == sorted(cfg.data.synthetic.instances)
    assert len(BigBirdObject(bb / "pepto_bismol").views()) == 3
    scans = [AVDScan(avd, s) for s in cfg.data.scans]
    assert len(scans) == 2 and sum(len(s.images) for s in scans) == m["extra"]["avd_images"]
    assert sum(len(i.boxes) for s in scans for i in s.images.values()) == m["extra"]["avd_boxes"]
    # Every instance is in some scan, each scan holds instances_per_scan of them.
    present = [set(s.present_instances) for s in scans]
    assert set().union(*present) == set(cfg.data.synthetic.instances)
    assert all(len(p) == cfg.data.synthetic.instances_per_scan for p in present)
    roots = json.loads((out / "roots.json").read_text())
    assert roots["source"] == "synthetic" and roots["scans"] == ["Home_001_1", "Home_002_1"]


def test_truth_sidecar_matches_the_generator(built):
    cfg = built
    truth = json.loads((cfg.stage_dir("data") / "truth.json").read_text())
    syn = cfg.data.synthetic
    for scan in cfg.data.scans:
        placed = scan_instances(syn.instances, cfg.data.scans, scan, syn.instances_per_scan)
        plan = plan_scan(syn, scan, cfg.data.seed, placed)
        t_scan = truth["scans"][scan]
        assert t_scan["scan"] == scan and t_scan["image_size"] == [96, 54]
        assert np.allclose(t_scan["intrinsics"], plan.K)
        assert np.allclose(t_scan["grid_points"], plan.room.grid_xy)
        assert set(t_scan["instances"]) == set(placed)
        for p in plan.room.placements:
            t = t_scan["instances"][p.name]
            assert t["id"] == p.instance_id and np.allclose(t["position"], p.position)
            assert t["yaw_deg"] == p.yaw_deg and t["base_height_m"] == p.base_height
            assert set(t["faces"]) == {"front", "left", "back", "right"}
    # The top level keeps the first scan's truth (the single-scan layout).
    assert truth["scan"] == cfg.data.scans[0] and truth["instances"] == truth["scans"][cfg.data.scans[0]]["instances"]
    # Designed aliasing: shared face textures, and one pair of near twins (all but one region shared).
    objs = truth["objects"]
    assert set(objs) == set(syn.instances)
    keys = [f["texture"] for t in objs.values() for f in t["faces"].values()]
    shared = {k for k in keys if k.startswith("shared/")}
    owners = {k: {n for n, t in objs.items() if any(f["texture"] == k for f in t["faces"].values())}
              for k in shared}
    assert sum(len(o) >= 2 for o in owners.values()) >= 4
    fam = {n: [t["faces"][r]["family"] for r in ("front", "left", "back", "right")] for n, t in objs.items()}
    twins = [(a, b) for a in fam for b in fam if a < b and sum(x == y for x, y in zip(fam[a], fam[b])) == 3]
    assert twins == [("honey_bunches_of_oats_honey_roasted", "honey_bunches_of_oats_with_almonds")]


def test_rerun_is_skipped_and_force_rewrites(built, capsys):
    cfg = built
    out = cfg.stage_dir("data")
    jpg = out / "bigbird" / "mahatma_rice" / "NP1_0.jpg"
    before_m, before_t = read_manifest(cfg, "data"), jpg.stat().st_mtime_ns
    capsys.readouterr()
    ensure(cfg, "data")
    assert "up to date" in capsys.readouterr().out
    assert read_manifest(cfg, "data") == before_m and jpg.stat().st_mtime_ns == before_t
    ensure(cfg, "data", force=True)
    assert jpg.stat().st_mtime_ns != before_t
    assert read_manifest(cfg, "data")["key"] == before_m["key"]


def test_output_does_not_depend_on_worker_count(built, tmp_config):
    two = tmp_config(merge(TINY, {"data": {"synthetic": {"workers": 2}}}))
    ensure(two, "data")
    a, b = _files(built.stage_dir("data")), _files(two.stage_dir("data"))
    assert a.keys() == b.keys()
    assert [k for k in a if a[k] != b[k]] == []
    # A different seed is a different data set, and a different cache key.
    other = tmp_config(merge(TINY, {"data": {"seed": 1}}))
    ensure(other, "data")
    assert read_manifest(other, "data")["key"] != read_manifest(built, "data")["key"]
    c = _files(other.stage_dir("data"))
    assert c["truth.json"] != a["truth.json"]


def test_real_source_validates_paths_and_fingerprints_inputs(built, tmp_config, tmp_path):
    src_bb, src_avd = data_roots(built)
    bb, avd = tmp_path / "bb", tmp_path / "avd"
    shutil.copytree(src_bb, bb)
    shutil.copytree(src_avd, avd)
    real = tmp_config({"data": {"source": "real", "bigbird_root": str(bb), "avd_root": str(avd),
                                "scans": ["Home_001_1"]}})
    assert data_roots(real) == (bb, avd)
    ensure(real, "data")
    roots = json.loads((real.stage_dir("data") / "roots.json").read_text())
    assert roots["bigbird_objects"] == list_objects(bb) and roots["avd_root"] == str(avd)
    assert not (real.stage_dir("data") / "bigbird").exists()  # nothing copied
    key = extra_key(real)
    assert key == extra_key(real)
    (avd / "Home_001_1" / "jpg_rgb" / "extra.txt").write_text("x")
    assert extra_key(real) != key
    assert extra_key(built) == ""

    (avd / "Home_001_1" / "annotations.json").unlink()
    with pytest.raises(BadInputError, match="annotations.json"):
        ensure(real, "data", force=True)
    missing = tmp_config({"data": {"source": "real", "bigbird_root": str(tmp_path / "nope"), "avd_root": str(avd)}})
    with pytest.raises(BadInputError, match="nope") as err:
        ensure(missing, "data")
    assert "data.bigbird_root" in str(err.value) and missing.source_path in str(err.value)
    wrong_scan = tmp_config({"data": {"source": "real", "bigbird_root": str(bb), "avd_root": str(avd),
                                      "scans": ["Home_002_1", "Home_003_1"]}})
    with pytest.raises(BadInputError, match="Home_003_1"):
        ensure(wrong_scan, "data")
