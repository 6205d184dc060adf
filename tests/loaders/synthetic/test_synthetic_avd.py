"""The AVD writer, read back with the real-format reader."""
from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from loaders.avd import AVDScan, difficulty, read_instance_map
from loaders.synthetic.avd_writer import (CLUSTER, MIN_VISIBLE_PX, STRUCT_FIELDS, Nuisance, capture,
                                          jitter_boxes, name_prefix, plan_scan, render_shot,
                                          visible_boxes, write_avd_scan)
from loaders.synthetic.bigbird_writer import object_meshes
from loaders.synthetic.objects import AVD_INSTANCE_MAP_TEXT, make_instance, rot_z
from loaders.synthetic.render import Camera, Light, render
from loaders.synthetic.scene import placed_meshes, scan_instances
from pipeline.infra.config import DEFAULT_INSTANCES, SyntheticDataConfig

SCAN = "Home_001_1"
SEED = 5
TINY = dataclasses.replace(SyntheticDataConfig(), instances=DEFAULT_INSTANCES[:6], room_size_m=(2.4, 2.1),
                           grid_step_m=0.6, avd_width=192, avd_height=108, distractors=2, occluders=2,
                           interpolated_fraction=0.3)
TARGET = "aunt_jemima_original_syrup"
SHARED_MAP = Path(__file__).resolve().parents[4] / "shared" / "formats" / "avd_instance_id_map.txt"


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    root = tmp_path_factory.mktemp("avd")
    plan = write_avd_scan(root, TINY, SCAN, SEED)
    return root, plan, AVDScan(root, SCAN)


def test_image_names_and_clusters(scan):
    root, plan, avd = scan
    names = sorted(p.name for p in (root / SCAN / "jpg_rgb").iterdir())
    assert names == list(avd.images) and len(names) == len(plan.room.grid_xy) * CLUSTER
    for i, n in enumerate(names, start=1):
        assert re.fullmatch(r"00011\d{6}0101\.jpg", n), n
        assert int(n[5:11]) == i  # 1-based, contiguous, sorted order = index order
    assert name_prefix("Office_012_2") == "10122"
    with pytest.raises(ValueError, match="data.scans"):
        name_prefix("Home_1_1")


def test_root_files(scan):
    root, plan, avd = scan
    text = (root / "instance_id_map.txt").read_text()
    assert text == AVD_INSTANCE_MAP_TEXT and len(text.splitlines()) == 34
    if SHARED_MAP.is_file():  # the real map, where the shared folder sits beside the clone
        assert read_instance_map(root / "instance_id_map.txt") == read_instance_map(SHARED_MAP)
    present = (root / SCAN / "present_instance_names.txt").read_text()
    assert present.endswith("\n") and present.splitlines() == list(TINY.instances)
    assert avd.present_instances == list(TINY.instances)
    cams = (root / SCAN / "cameras.txt").read_text().splitlines()
    assert [ln.startswith("#") for ln in cams] == [True, True, True, False]
    assert cams[3].split()[:4] == ["1", "OPENCV", "192", "108"]
    assert np.allclose(avd.intrinsics(), plan.K, atol=1e-5)


def test_poses_read_back_equal_the_generator(scan):
    _, plan, avd = scan
    for s in plan.shots:
        img = avd.images[s.name]
        assert np.abs(img.position - np.array(s.position)).max() < 1e-6
        d = (img.heading - math.radians(s.heading_deg) + math.pi) % (2 * math.pi) - math.pi
        assert abs(d) < 1e-6
        assert img.registered == s.registered
    assert np.allclose(avd.up, [0.0, -1.0, 0.0], atol=1e-9)  # recon y points down


def test_image_structs_fields_and_interpolated_entries(scan):
    root, plan, _ = scan
    m = scipy.io.loadmat(root / SCAN / "image_structs.mat")
    arr = m["image_structs"]
    assert arr.shape == (1, len(plan.shots)) and arr.dtype.names == STRUCT_FIELDS
    assert m["scale"].shape == (1, 1) and m["scale"][0][0] > 1.0
    names = [arr["image_name"][0][i][0] for i in range(arr.shape[1])]
    assert names == sorted(names)
    shots = {s.name: s for s in plan.shots}
    n_interp = 0
    for i, name in enumerate(names):
        el = arr[0][i]
        s = shots[name]
        world = el["world_pos"].reshape(3)
        direction = el["direction"].reshape(3)
        assert np.isclose(np.linalg.norm(direction), 1.0)
        assert np.allclose(el["scaled_world_pos"].reshape(3), world * m["scale"][0][0])
        if s.registered:
            R, t, q = el["R"], el["t"].reshape(3), el["quat"].reshape(4)
            assert np.allclose(world, -R.T @ t) and np.allclose(direction, R[2])
            qw, qx, qy, qz = q
            Rq = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                           [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                           [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
            assert np.allclose(Rq, R, atol=1e-9) and qw >= 0
            assert el["image_id"][0] and el["camera_id"][0] == "1"
        else:
            n_interp += 1
            assert el["R"].size == 0 and el["t"].size == 0 and el["quat"].size == 0
            assert el["image_id"].size == 0 or el["image_id"][0] == ""
    # Never a whole cluster: at least two registered images per grid point.
    for k in range(len(plan.room.grid_xy)):
        assert sum(s.registered for s in plan.shots if s.cluster == k) >= 2
    assert abs(n_interp / len(names) - TINY.interpolated_fraction) < 0.1 and n_interp % 2 == 0


def test_move_pointers(scan):
    _, plan, avd = scan
    by_name = {s.name: s for s in plan.shots}
    moved = 0
    for s in plan.shots:
        mv = avd.images[s.name].moves
        ccw = by_name[mv["rotate_ccw"]]
        assert ccw.cluster == s.cluster and ccw.j == (s.j + 1) % CLUSTER
        assert math.isclose((ccw.heading_deg - s.heading_deg) % 360, 30.0)
        assert by_name[mv["rotate_cw"]].j == (s.j - 1) % CLUSTER
        for key, turn in (("forward", 0), ("left", 90), ("backward", 180), ("right", 270)):
            if not mv[key]:
                continue
            moved += 1
            d = np.array(by_name[mv[key]].position) - np.array(s.position)
            assert abs(np.linalg.norm(d) - TINY.grid_step_m) < 0.05
            ang = math.degrees(math.atan2(d[1], d[0])) - (s.heading_deg + turn)
            assert abs((ang + 180) % 360 - 180) <= 35, (key, s.name)
            assert by_name[mv[key]].j == s.j
    assert moved > 0


def test_boxes_contain_every_visible_pixel_of_their_instance(scan):
    _, plan, avd = scan
    ids_all = {p.instance_id for p in plan.room.placements}
    n_boxes = 0
    for s in plan.shots[::3]:
        _, ids = render_shot(plan, s)
        boxes = {b.instance_id: b for b in avd.images[s.name].boxes}
        for iid in ids_all:
            ys, xs = np.nonzero(ids == iid)
            if len(xs) < MIN_VISIBLE_PX:
                assert iid not in boxes
                continue
            b = boxes[iid]
            true = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
            # Annotation error: each side within the configured jitter (clipped to the image).
            assert np.abs(np.array([b.x0, b.y0, b.x1, b.y1]) - true).max() <= plan.nuisance.box_jitter_px
            assert b.difficulty == difficulty(b.x0, b.y0, b.x1, b.y1)
            n_boxes += 1
    assert n_boxes > 5


def test_difficulty_rule_examples():
    # docs/formats/avd.md §3: L = max(w, h), s = min(w, h).
    assert difficulty(0, 0, 300, 100) == 1
    assert difficulty(0, 0, 250, 80) == 2 and difficulty(0, 0, 250, 60) == 3
    assert difficulty(0, 0, 60, 30) == 4 and difficulty(0, 0, 49, 40) == 5


def test_boxes_point_at_the_true_object_position(scan):
    """A box centre's bearing, from the reader's pose, passes by the sidecar's object position."""
    _, plan, avd = scan
    K, p = plan.K, math.radians(plan.pitch_deg)
    tried = 0
    for pl in plan.room.placements:
        for img, b in avd.boxes_of(pl.name, max_difficulty=5):
            if b.x0 == 0 or b.x1 == plan.width:
                continue  # cut by the image border: the box centre is not the object's
            u, v = (b.x0 + b.x1 - 1) / 2, (b.y0 + b.y1 - 1) / 2
            lateral = (u - K[0, 2]) / K[0, 0]
            ahead = math.cos(p) + math.sin(p) * (v - K[1, 2]) / K[1, 1]
            ang = img.heading - math.atan2(lateral, ahead)
            rel = np.array(pl.position) - img.position
            miss = abs(rel[0] * math.sin(ang) - rel[1] * math.cos(ang))
            # + what the annotation jitter can move the box centre's bearing at this distance
            jitter = plan.nuisance.box_jitter_px / K[0, 0] * np.linalg.norm(rel)
            assert miss < 0.1 + jitter, (img.name, pl.name, miss)
            tried += 1
    assert tried > 5


@pytest.mark.parametrize("bearing", [15.0, 100.0, 200.0, 290.0])
def test_room_placement_matches_the_bigbird_table_frame(bearing):
    """A room camera at ground p sees the same faces as a BigBIRD camera at Rot(-yaw)(p - pos)."""
    plan = plan_scan(TINY, SCAN, SEED)
    pl = plan.room.placement(TARGET)
    inst = make_instance(TARGET, SEED)
    K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
    flat = Light(ambient=1.0, diffuse=0.0)
    b = math.radians(bearing)
    pos = np.array(pl.position)
    cam_xy = pos + 0.6 * np.array([math.cos(b), math.sin(b)])
    room_cam = Camera.look_at([*cam_xy, pl.base_height + 0.3], [*pos, pl.base_height + 0.12], K, 160, 120)
    rel = rot_z(-pl.yaw_deg)[:2, :2] @ (cam_xy - pos)
    table_cam = Camera.look_at([*rel, 0.3], [0.0, 0.0, 0.12], K, 160, 120)
    room_ids = render(room_cam, placed_meshes(pl, SEED), flat, face_labels=True).ids
    table_ids = render(table_cam, object_meshes(inst), flat, face_labels=True).ids
    assert (room_ids > 0).sum() > 500
    assert (room_ids != table_ids).mean() < 0.005
    labels = lambda ids: {int(v) for v, n in zip(*np.unique(ids, return_counts=True)) if v and n >= 20}  # noqa: E731
    assert labels(room_ids) == labels(table_ids)
    # And the faces seen are those whose outward normal faces the camera's direction.
    side = [f for f in inst.faces if f.region != "cap"]
    best = max(side, key=lambda f: f.normal[:2] @ rel / np.linalg.norm(rel))
    assert best.label + 1 in labels(table_ids)


def test_deterministic_and_seed_dependent(tmp_path):
    small = dataclasses.replace(TINY, avd_width=96, avd_height=54)
    a = write_avd_scan(tmp_path / "a", small, SCAN, SEED)
    write_avd_scan(tmp_path / "b", small, SCAN, SEED)
    for rel in ("annotations.json", "image_structs.mat", "present_instance_names.txt",
                f"jpg_rgb/{a.shots[7].name}"):
        assert (tmp_path / "a" / SCAN / rel).read_bytes() == (tmp_path / "b" / SCAN / rel).read_bytes(), rel
    other = plan_scan(small, SCAN, SEED + 1)
    assert other.room.placement(TARGET).yaw_deg != a.room.placement(TARGET).yaw_deg


def test_bad_settings_are_errors_naming_the_key():
    with pytest.raises(ValueError, match="data.synthetic.instances"):
        plan_scan(dataclasses.replace(TINY, instances=("aunt_jemima_original_syrup", "not_an_object")), SCAN, 0)
    with pytest.raises(ValueError, match="room_size_m"):
        plan_scan(dataclasses.replace(TINY, room_size_m=(1.5, 3.0)), SCAN, 0)
    with pytest.raises(ValueError, match="data.scans"):
        plan_scan(TINY, "Kitchen_1", 0)


def test_annotations_json_layout(scan):
    root, _, _ = scan
    ann = json.loads((root / SCAN / "annotations.json").read_text())
    for name, entry in ann.items():
        assert set(entry) == {"bounding_boxes", "rotate_ccw", "rotate_cw", "forward", "backward", "left", "right"}
        for b in entry["bounding_boxes"]:
            assert len(b) == 6 and all(isinstance(v, int) for v in b)
        assert len({b[4] for b in entry["bounding_boxes"]}) == len(entry["bounding_boxes"])


def test_scan_instances_cover_every_instance_and_each_scan_holds_enough():
    names = DEFAULT_INSTANCES
    scans = ("Home_001_1", "Home_002_1")
    per = {s: scan_instances(names, scans, s, 9) for s in scans}
    assert all(len(v) == 9 and len(set(v)) == 9 for v in per.values())
    assert set().union(*per.values()) == set(names) and per[scans[0]][0] == names[0]
    assert scan_instances(names, scans, scans[1], 0) == tuple(names)
    with pytest.raises(ValueError, match="data.scans"):
        scan_instances(names, scans, "Home_003_1", 9)
    # Another scan name is another home: a different layout for the same instances.
    a, b = plan_scan(TINY, "Home_001_1", SEED), plan_scan(TINY, "Home_002_1", SEED)
    assert a.room.placement(TARGET).position != b.room.placement(TARGET).position


def test_occluders_stand_right_beside_instances(scan):
    _, plan, _ = scan
    occ = [c for c in plan.room.clutter if c.key.startswith("occluder/")]
    assert len(occ) == TINY.occluders
    for c in occ:
        gap = min(np.hypot(*(np.array(c.position) - p.position)) - p.radius for p in plan.room.placements)
        assert 0 < gap < 0.15


def test_auto_exposure_pulls_brightness_towards_mid_grey_and_blur_smooths():
    rng = np.random.default_rng(0)
    dark, bright = np.full((20, 30, 3), 40, np.uint8), np.full((20, 30, 3), 200, np.uint8)
    nz = Nuisance(auto_exposure=0.6)
    for img in (dark, bright):
        out = capture(img, nz, rng).mean()
        assert abs(out - 118) < abs(img.mean() - 118)
    assert (capture(dark, Nuisance(), rng) == dark).all()
    edge = np.zeros((21, 21, 3), np.uint8)
    edge[:, 10:] = 255
    out = capture(edge, Nuisance(blur_fraction=1.0, blur_px=9), rng)
    assert 0 < out[10, 10, 0] < 255 and (out[:, 0] == 0).all()


def test_box_jitter_keeps_boxes_valid():
    rng = np.random.default_rng(0)
    boxes = [[0, 0, 5, 4, 2, 5], [100, 50, 190, 108, 7, 3]]
    for _ in range(50):
        for x0, y0, x1, y1, iid, d in jitter_boxes(boxes, 3, 192, 108, rng):
            assert 0 <= x0 < x1 <= 192 and 0 <= y0 < y1 <= 108 and x1 - x0 >= 2 and y1 - y0 >= 2
            assert d == difficulty(x0, y0, x1, y1)
    assert jitter_boxes(boxes, 0, 192, 108, rng) == boxes


def test_visible_boxes_equal_the_extent_of_each_label():
    """The boxes from label counts and mask projections are each instance's pixel extent, as the
    plain coordinate search gives it; too few pixels, an absent id or an empty buffer give none."""
    rng = np.random.default_rng(3)
    for trial in range(30):
        ids = np.zeros((rng.integers(1, 40), rng.integers(1, 50)), np.int32)
        for label in rng.integers(1, 12, 5):
            y, x = rng.integers(0, ids.shape[0]), rng.integers(0, ids.shape[1])
            ids[y:y + rng.integers(1, 20), x:x + rng.integers(1, 25)] = label
        ids[rng.random(ids.shape) < 0.05] = 3  # scattered pixels: a label split in pieces
        wanted = [3, 5, 7, 11, 40]
        expect = []
        for iid in wanted:
            ys, xs = np.nonzero(ids == iid)
            if len(xs) >= MIN_VISIBLE_PX:
                x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
                expect.append([x0, y0, x1, y1, iid, difficulty(x0, y0, x1, y1)])
        assert visible_boxes(ids, wanted) == expect
    assert visible_boxes(np.zeros((0, 0), np.int32), [1]) == []
