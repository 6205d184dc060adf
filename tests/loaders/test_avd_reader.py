"""AVD reader on tiny hand-made scans (tests/support/readers_fixtures.py): poses in the ground frame,
boxes, moves, interpolated entries, intrinsics and every kind of bad input."""
from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from loaders.avd import AVDBox, AVDScan, KINECT_K, difficulty, read_instance_map
from loaders.errors import BadInputError, SkipLog

from tests.support.readers_fixtures import INSTANCE_MAP_LINES, avd_name, make_avd_scan

SCAN = "Home_001_1"


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@pytest.fixture()
def scan(tmp_path):
    truth = make_avd_scan(tmp_path)
    return AVDScan(tmp_path, SCAN), truth


def n(i: int) -> str:
    return avd_name(SCAN, i)


# ---- happy path -------------------------------------------------------------------------------

def test_scan_metadata(scan, tmp_path):
    s, truth = scan
    assert s.root == tmp_path and s.scan == SCAN and s.folder == tmp_path / SCAN
    assert s.scale == pytest.approx(250.0)
    assert list(s.images) == sorted(truth["names"]) and len(s.images) == 24
    assert s.present_instances == ["aunt_jemima_original_syrup", "crystal_hot_sauce"]
    assert s.instance_ids["crystal_hot_sauce"] == 7 and s.instance_names[2] == "aunt_jemima_original_syrup"
    assert s.instance_ids["background"] == 0
    img = s.images[n(1)]
    assert img.path == tmp_path / SCAN / "jpg_rgb" / n(1)
    assert img.moves == {"forward": n(13), "backward": "", "left": "", "right": "",
                         "rotate_cw": n(12), "rotate_ccw": n(2)}
    rgb = s.read_image(n(14))
    assert rgb.shape == (270, 480, 3) and rgb.dtype == np.uint8
    # the fixture paints (R, G, B) = (60 + 7j, 120, 90 + 40k): image 14 is j = 1, k = 1
    np.testing.assert_allclose(rgb.reshape(-1, 3).mean(axis=0), (67, 120, 130), atol=3)


def test_positions_and_headings_match_truth(scan):
    s, truth = scan
    for name, img in s.images.items():
        np.testing.assert_allclose(img.position, truth["position"][name], atol=1e-9)
        assert wrap(img.heading - truth["heading"][name]) == pytest.approx(0.0, abs=1e-9)
    # the writer convention: recon x = ground x, recon y = -height, recon z = ground y
    np.testing.assert_allclose(s.up, [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(s.axes, [[1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_ground_frame_right_handed_and_ccw_is_plus_30(scan):
    s, _ = scan
    e1, e2 = s.axes
    np.testing.assert_allclose(np.cross(e1, e2), s.up, atol=1e-12)
    for name, img in s.images.items():
        ccw = s.images[img.moves["rotate_ccw"]]
        assert wrap(ccw.heading - img.heading) == pytest.approx(math.radians(30), abs=1e-9)
    # "forward" from image 1 leads to the next grid point, 0.3 m away
    a, b = s.images[n(1)], s.images[n(13)]
    step = b.position - a.position
    assert np.linalg.norm(step) == pytest.approx(0.3, abs=1e-9)


def test_interpolated_entries(scan):
    s, truth = scan
    for name, img in s.images.items():
        assert img.registered == (name not in truth["interpolated"])
        assert set(img.struct) == {"image_name", "t", "R", "world_pos", "direction", "quat",
                                   "scaled_world_pos", "image_id", "camera_id", "cluster_id",
                                   "rotate_cw", "rotate_ccw", "translate_forward",
                                   "translate_backward", "translate_right", "translate_left"}
    interp = s.images[n(2)]
    assert not interp.registered
    for f in ("R", "t", "quat"):
        assert interp.struct[f].size == 0
    assert interp.struct["image_id"] == "" and interp.struct["camera_id"] == ""
    reg = s.images[n(1)]
    assert reg.struct["R"].shape == (3, 3) and reg.struct["image_id"] == "1"
    # -1 in a neighbour field means "no neighbour"; names stay names
    assert reg.struct["translate_left"] == "" and reg.struct["rotate_ccw"] == n(2)


def test_difficulty_rule():
    assert difficulty(0, 0, 250, 80) == 2
    assert difficulty(0, 0, 250, 60) == 3
    assert difficulty(0, 0, 80, 250) == 2          # orientation does not matter
    assert difficulty(10, 10, 310, 110) == 1       # 300x100: thresholds are inclusive
    assert difficulty(10, 10, 309, 110) == 2
    assert difficulty(0, 0, 50, 30) == 4 and difficulty(0, 0, 49, 30) == 5
    assert difficulty(0, 0, 20, 10) == 5


def test_boxes_and_boxes_of_filter_by_difficulty(scan):
    s, truth = scan
    assert s.images[n(2)].boxes[0] == truth_box(truth, 0, 1, 0)
    for img in s.images.values():
        for b in img.boxes:
            assert b.difficulty == difficulty(b.x0, b.y0, b.x1, b.y1)  # the fixture follows the rule
    aunt = s.boxes_of("aunt_jemima_original_syrup")
    assert [(img.name, b.difficulty) for img, b in aunt] == [(n(1), 1), (n(2), 2), (n(3), 3), (n(13), 4)]
    assert [img.name for img, _ in s.boxes_of("aunt_jemima_original_syrup", max_difficulty=2)] == [n(1), n(2)]
    crystal = s.boxes_of("crystal_hot_sauce", max_difficulty=4)
    assert [(img.name, (b.x0, b.y0, b.x1, b.y1)) for img, b in crystal] == [(n(18), (200, 100, 280, 200))]
    assert len(s.boxes_of("crystal_hot_sauce")) == 2
    assert s.boxes_of("advil_liqui_gels") == []
    with pytest.raises(KeyError, match="red_cup"):
        s.boxes_of("red_cup")


def truth_box(truth, k, j, i):
    return AVDBox(*truth["boxes"][(k, j)][i])


def test_intrinsics_fallback_and_cameras_txt(tmp_path):
    make_avd_scan(tmp_path)            # 480x270 = a quarter of 1920x1080
    K = AVDScan(tmp_path, SCAN).intrinsics()
    np.testing.assert_allclose(K, np.diag([0.25, 0.25, 1]) @ KINECT_K)
    assert K[0, 0] == pytest.approx(1070.0016 / 4) and K[1, 2] == pytest.approx(545.7610 / 4)
    cam = ("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
           "# Number of cameras: 1\n1 OPENCV 1920 1080 1000 1010 960 540 0.1 -0.2 0.001 0.002\n")
    make_avd_scan(tmp_path / "b", cameras_txt=cam)
    K = AVDScan(tmp_path / "b", SCAN).intrinsics()
    np.testing.assert_allclose(K, [[250, 0, 240], [0, 252.5, 135], [0, 0, 1]])


def test_real_instance_map_if_available():
    real = Path(__file__).resolve().parents[2] / "docs" / "formats" / "avd_instance_id_map.txt"
    m = read_instance_map(real)
    assert len(m) == 34 and m["background"] == 0 and m["red_cup"] == 33
    assert m["spongebob_squarepants_fruit_snaks"] == 25


def test_instance_map_errors(tmp_path):
    p = tmp_path / "instance_id_map.txt"
    p.write_text("\n".join(INSTANCE_MAP_LINES[:3]) + "\nadvil_liqui_gels 9\n")
    with pytest.raises(BadInputError, match="line 4.*twice"):
        read_instance_map(p)
    p.write_text("background 0\nred_cup x\n")
    with pytest.raises(BadInputError, match="line 2"):
        read_instance_map(p)


# ---- a rotated, tilted, scaled reconstruction -------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 3])
def test_arbitrary_recon_frame_gives_rigid_right_handed_ground(tmp_path, seed):
    pts = ((0.0, 0.0), (0.9, 0.0), (0.3, 0.6))  # an L: orientation (handedness) is observable
    truth = make_avd_scan(tmp_path, points=pts, recon_seed=seed, recon_scale=3.7)
    s = AVDScan(tmp_path, SCAN)
    e1, e2 = s.axes
    np.testing.assert_allclose(np.cross(e1, e2), s.up, atol=1e-12)
    names = sorted(s.images)
    P = np.array([s.images[x].position for x in names])
    T = np.array([truth["position"][x] for x in names])
    for i, j in itertools.combinations(range(len(names)), 2):
        assert np.linalg.norm(P[i] - P[j]) == pytest.approx(np.linalg.norm(T[i] - T[j]), abs=1e-6)
    # a proper rotation (no mirror): the signed area of the L keeps its sign
    def area(a, b, c):
        return (b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0]
    i0, i1, i2 = (names.index(n(12 * k + 1)) for k in range(3))
    assert area(P[i0], P[i1], P[i2]) == pytest.approx(area(T[i0], T[i1], T[i2]), abs=1e-6)
    for name, img in s.images.items():
        ccw = s.images[img.moves["rotate_ccw"]]
        assert wrap(ccw.heading - img.heading) == pytest.approx(math.radians(30), abs=1e-9)
    # headings turn with the same rigid map as positions: the bearing of point 1 seen from
    # point 0, relative to each camera's heading, matches the truth
    bearing = math.atan2(*(P[i1] - P[i0])[::-1])
    bearing_t = math.atan2(*(T[i1] - T[i0])[::-1])
    for name, img in s.images.items():
        assert wrap((bearing - img.heading) - (bearing_t - truth["heading"][name])) == \
            pytest.approx(0.0, abs=1e-9)


# ---- bad input --------------------------------------------------------------------------------

def test_missing_scan_folder(tmp_path):
    make_avd_scan(tmp_path)
    with pytest.raises(BadInputError, match="scan folder is missing") as e:
        AVDScan(tmp_path, "Home_009_1")
    assert "Home_009_1" in str(e.value)
    (tmp_path / "instance_id_map.txt").unlink()
    with pytest.raises(BadInputError, match="instance id map is missing"):
        AVDScan(tmp_path, SCAN)


def test_annotation_naming_missing_image(tmp_path):
    truth = make_avd_scan(tmp_path)
    (truth["folder"] / "jpg_rgb" / n(3)).unlink()
    with pytest.raises(BadInputError, match="not in jpg_rgb") as e:
        AVDScan(tmp_path, SCAN)
    assert "annotations.json" in str(e.value) and n(3) in str(e.value)
    skip = SkipLog("annotation")
    s = AVDScan(tmp_path, SCAN, skip=skip)
    assert skip.count == 1 and n(3) not in s.images and len(s.images) == 23


def _edit_box(i_img: int, box):
    def edit(ann):
        ann[n(i_img)]["bounding_boxes"][0] = box
    return edit


@pytest.mark.parametrize("box,problem", [
    ([100, 50, 100, 130, 2, 2], "degenerate"),      # x1 == x0
    ([100, 130, 350, 50, 2, 2], "degenerate"),      # y1 < y0
    ([100, 50, 1000, 130, 2, 2], "outside"),        # 380 of its 900 px width inside the 480-wide image
    ([-300, 50, 100, 130, 2, 2], "outside"),        # a quarter of it inside
    ([100, 50, 350, 130, 2, 6], "difficulty 6"),
    ([100, 50, 350, 130, 99, 2], "unknown instance id 99"),
    ([100, 50, 350, 130, 2], "is not [x0"),
])
def test_bad_box_raises_or_is_skipped(tmp_path, box, problem):
    make_avd_scan(tmp_path, annotation_edit=_edit_box(2, box))
    with pytest.raises(BadInputError, match=problem.replace("[", r"\[")) as e:
        AVDScan(tmp_path, SCAN)
    assert str(tmp_path / SCAN / "annotations.json") in str(e.value) and n(2) in str(e.value)
    skip = SkipLog("box")
    s = AVDScan(tmp_path, SCAN, skip=skip)
    assert skip.count == 1
    # only the bad box is gone; the other box of that image and every image are kept
    assert len(s.images) == 24
    assert [(b.instance_id, b.difficulty) for b in s.images[n(2)].boxes] == [(7, 5)]


def test_box_one_past_the_edge_is_clipped(tmp_path):
    make_avd_scan(tmp_path, annotation_edit=_edit_box(2, [400, 200, 481, 271, 2, 4]))
    s = AVDScan(tmp_path, SCAN)
    b = s.images[n(2)].boxes[0]
    assert (b.x0, b.y0, b.x1, b.y1) == (400, 200, 480, 270)
    assert s.box_notes.clipped == 0  # MATLAB's inclusive edge, not a repair


@pytest.mark.parametrize("box,clipped", [
    ([420, 200, 491, 271, 2, 4], (420, 200, 480, 270)),   # 11 px past, as in the real Home_007_1
    ([-5, 50, 100, 130, 2, 2], (0, 50, 100, 130)),
])
def test_box_past_the_edge_is_clipped_and_counted(tmp_path, box, clipped):
    make_avd_scan(tmp_path, annotation_edit=_edit_box(2, box))
    s = AVDScan(tmp_path, SCAN)
    b = s.images[n(2)].boxes[0]
    assert (b.x0, b.y0, b.x1, b.y1) == clipped
    assert s.box_notes.clipped == 1 and b.difficulty == box[5]  # the stated level stays


def test_difficulty_zero_gets_the_size_rule(tmp_path):
    """The real files hold difficulty 0 (not assigned): kept, with the level the size gives."""
    make_avd_scan(tmp_path, annotation_edit=_edit_box(2, [100, 50, 350, 130, 2, 0]))
    s = AVDScan(tmp_path, SCAN)
    b = s.images[n(2)].boxes[0]
    assert (b.instance_id, b.difficulty) == (2, 2)   # 250 x 80 -> 2
    assert s.box_notes.unassigned == 1 and len(s.images[n(2)].boxes) == 2


def test_missing_struct_entry(tmp_path):
    def drop(structs):
        structs[:] = [s for s in structs if s["image_name"] != n(7)]
    make_avd_scan(tmp_path, struct_edit=drop)
    with pytest.raises(BadInputError, match="no image_structs entry") as e:
        AVDScan(tmp_path, SCAN)
    assert "image_structs.mat" in str(e.value) and n(7) in str(e.value)
    skip = SkipLog()
    s = AVDScan(tmp_path, SCAN, skip=skip)
    assert skip.count == 1 and n(7) not in s.images and len(s.images) == 23


@pytest.mark.parametrize("index,field", [(2, "world_pos"), (4, "t")])  # interpolated / registered
def test_nan_position(tmp_path, index, field):
    def nan(structs):
        s = next(s for s in structs if s["image_name"] == n(index))
        s[field] = s[field].copy()
        s[field][0, 0] = np.nan
    make_avd_scan(tmp_path, struct_edit=nan)
    with pytest.raises(BadInputError, match="NaN") as e:
        AVDScan(tmp_path, SCAN)
    assert "image_structs.mat" in str(e.value) and n(index) in str(e.value) and field in str(e.value)
    skip = SkipLog()
    s = AVDScan(tmp_path, SCAN, skip=skip)
    assert skip.count == 1 and n(index) not in s.images
    for name, img in s.images.items():  # the rest still read right
        assert np.all(np.isfinite(img.position))


def test_corrupt_image(tmp_path):
    truth = make_avd_scan(tmp_path)
    p = truth["folder"] / "jpg_rgb" / n(5)
    p.write_bytes(p.read_bytes()[:200])
    s = AVDScan(tmp_path, SCAN)  # no boxes in image 5: its header is not needed to load
    with pytest.raises(BadInputError, match="JPEG") as e:
        s.read_image(n(5))
    assert str(p) in str(e.value)


def test_missing_files_and_malformed_structs(tmp_path):
    truth = make_avd_scan(tmp_path)
    mat = truth["folder"] / "image_structs.mat"
    mat.write_bytes(b"not a mat file")
    with pytest.raises(BadInputError, match="image_structs.mat"):
        AVDScan(tmp_path, SCAN)
    mat.unlink()
    with pytest.raises(BadInputError, match="image_structs.mat is missing"):
        AVDScan(tmp_path, SCAN)
    ann = truth["folder"] / "annotations.json"
    ann.write_text(json.dumps({n(1): {"rotate_cw": ""}}))
    with pytest.raises(BadInputError, match="bounding_boxes"):
        AVDScan(tmp_path, SCAN)


def test_all_unregistered_has_no_up(tmp_path):
    make_avd_scan(tmp_path, interpolated=tuple(range(24)))
    with pytest.raises(BadInputError, match="no registered image"):
        AVDScan(tmp_path, SCAN)


def test_unknown_present_instance(tmp_path):
    truth = make_avd_scan(tmp_path)
    (truth["folder"] / "present_instance_names.txt").write_text("aunt_jemima_original_syrup\nred_cup\n")
    with pytest.raises(BadInputError, match="red_cup"):
        AVDScan(tmp_path, SCAN)


def test_present_instances_fallback_when_file_missing(tmp_path):
    truth = make_avd_scan(tmp_path)
    (truth["folder"] / "present_instance_names.txt").unlink()
    s = AVDScan(tmp_path, SCAN)
    assert s.present_instances == ["aunt_jemima_original_syrup", "crystal_hot_sauce"]
