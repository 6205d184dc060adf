"""BigBIRD reader on a tiny hand-made object folder (tests/support/readers_fixtures.py)."""
from __future__ import annotations

import cv2
import h5py
import numpy as np
import pytest

from loaders.bigbird import BigBirdObject, list_objects
from loaders.jpeg import jpeg_size, read_rgb
from loaders.errors import BadInputError, SkipLog
from loaders.pbm import encode_pbm

from tests.support.readers_fixtures import make_bigbird_object, rot_z, write_jpeg


@pytest.fixture()
def obj(tmp_path):
    truth = make_bigbird_object(tmp_path / "bigbird")
    return BigBirdObject(truth["folder"]), truth


def test_list_objects_needs_calibration(tmp_path, obj):
    (tmp_path / "bigbird" / "not_an_object").mkdir()
    (tmp_path / "bigbird" / "zz_readme.txt").write_text("x")
    assert list_objects(tmp_path / "bigbird") == ["aunt_jemima_original_syrup"]
    with pytest.raises(BadInputError, match="missing"):
        list_objects(tmp_path / "nowhere")


def test_views_sorted_numerically_unpadded_names(obj):
    o, truth = obj
    # Files that are not Carmine RGB views must be ignored.
    (o.folder / "N1_3.jpg").write_bytes(b"canon")
    (o.folder / "NP1_003.jpg").write_bytes(b"padded name: not BigBIRD")
    (o.folder / "NP1_0.h5").write_bytes(b"depth")
    views = o.views(cameras=(3, 1))
    assert [(v.camera, v.angle) for v in views] == [(c, a) for c in (1, 3) for a in truth["angles"]]
    v = views[4]  # angle 12 sorts after 9, not after 0 as text would
    assert (v.camera, v.angle) == (1, 12)
    assert v.image_path.name == "NP1_12.jpg"
    assert v.mask_path == o.folder / "masks" / "NP1_12_mask.pbm"
    assert v.object == "aunt_jemima_original_syrup"
    assert o.views(cameras=(5,)) == []


def test_camera_pose_formula_and_geometry(obj):
    o, truth = obj
    for c in truth["cameras"]:
        for a in truth["angles"]:
            H = o.camera_pose(c, a)
            # the documented chain with the matrices written to disk
            expected = truth["poses"][a] @ np.linalg.inv(truth["H_c_from_5"][c])
            np.testing.assert_allclose(H, expected, atol=1e-9, rtol=0)
            # and the geometry it must produce: the angle-0 rig turned by a about table z
            np.testing.assert_allclose(H, rot_z(a) @ truth["T"][c], atol=1e-9, rtol=0)
            p = o.camera_position(c, a)
            assert p.shape == (3,)
            np.testing.assert_allclose(p, (rot_z(a) @ truth["T"][c])[:3, 3], atol=1e-9, rtol=0)
    # turning the table keeps height and distance to the axis, and moves the camera by a
    p0, p9 = o.camera_position(1, 0), o.camera_position(1, 9)
    assert p0[2] == pytest.approx(p9[2], abs=1e-12)
    assert np.hypot(*p0[:2]) == pytest.approx(np.hypot(*p9[:2]), abs=1e-12)
    turn = np.degrees(np.arctan2(p9[1], p9[0]) - np.arctan2(p0[1], p0[0]))
    assert turn == pytest.approx(9.0, abs=1e-9)
    np.testing.assert_allclose(o.intrinsics(3), truth["K"][3])


def test_iter_views_reads_images_masks_and_boxes(obj):
    o, truth = obj
    recs = list(o.iter_views(cameras=(1, 3)))
    assert len(recs) == len(truth["cameras"]) * len(truth["angles"])
    for r in recs:
        key = (r.view.camera, r.view.angle)
        assert r.image.dtype == np.uint8 and r.image.shape == (48, 64, 3)
        assert r.mask.dtype == bool and r.mask.shape == (48, 64)
        # the speck and the smaller blob are ignored: the box is exactly the drawn rectangle
        assert r.box == truth["boxes"][key]
        x0, y0, x1, y1 = r.box
        # RGB order: the object was drawn red (200, 40, 30), so R dominates inside the box
        inside = r.image[y0 + 2:y1 - 2, x0 + 2:x1 - 2].reshape(-1, 3).mean(axis=0)
        assert inside[0] > 150 and inside[2] < 80
        np.testing.assert_allclose(r.pose, o.camera_pose(*key))


def test_object_box_ignores_speck_and_exclusive_ends(obj):
    o, _ = obj
    m = np.zeros((48, 64), bool)
    m[10:20, 30:45] = True
    m[0, 0] = m[47, 63] = True      # single-pixel specks at the corners
    m[30:32, 5:7] = True            # a 2x2 speck
    assert o.object_box(m) == (30, 10, 45, 20)
    # a bigger second component wins over a smaller one
    m[25:45, 2:30] = True
    assert o.object_box(m) == (2, 25, 30, 45)


def _box_of_whole_image(mask, k):
    """The largest component's box, labelled over the whole image (the reader's route before it
    labelled only the rectangle of what survives the opening)."""
    opened = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    n, _, stats, _ = cv2.connectedComponentsWithStats(opened, connectivity=8)
    if n <= 1:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x0, y0, w, h = (int(v) for v in stats[best, :4])
    return x0, y0, x0 + w, y0 + h


def test_object_box_equals_labelling_the_whole_image_ties_included():
    from loaders.bigbird import mask_box

    rng = np.random.default_rng(0)
    ties = 0
    for _ in range(400):
        H, W = (int(v) for v in rng.integers(20, 90, 2))
        m = np.zeros((H, W), bool)
        s = int(rng.integers(3, 9))
        n_sq = int(rng.integers(1, 5))
        for _ in range(n_sq):          # equally large squares: which one wins is the labels' order
            y, x = int(rng.integers(0, H - s)), int(rng.integers(0, W - s))
            m[y:y + s, x:x + s] = True
        m[rng.integers(0, H, 15), rng.integers(0, W, 15)] = True   # specks
        k = int(rng.integers(1, 5))
        want = _box_of_whole_image(m, k)
        if want is None:
            with pytest.raises(BadInputError, match="only specks"):
                mask_box(m, k)
            continue
        ties += n_sq > 1
        assert mask_box(m, k) == want
    assert ties > 100


def test_jpeg_size_matches_decode(obj):
    o, _ = obj
    v = o.views()[0]
    assert jpeg_size(v.image_path) == (64, 48)
    assert read_rgb(v.image_path).shape == (48, 64, 3)


# ---- bad input --------------------------------------------------------------------------------

def test_missing_object_folder_and_calibration(tmp_path, obj):
    with pytest.raises(BadInputError, match="object folder is missing") as e:
        BigBirdObject(tmp_path / "bigbird" / "no_such_object")
    assert "no_such_object" in str(e.value)
    o, _ = obj
    (o.folder / "calibration.h5").unlink()
    with pytest.raises(BadInputError, match="calibration") as e:
        BigBirdObject(o.folder)
    assert str(o.folder / "calibration.h5") in str(e.value)


def test_missing_pose_file(obj):
    o, _ = obj
    path = o.folder / "poses" / "NP5_6_pose.h5"
    path.unlink()
    with pytest.raises(BadInputError, match="missing") as e:
        o.camera_pose(1, 6)
    assert str(path) in str(e.value)
    o.camera_pose(1, 3)  # other angles still fine


def test_missing_h5_key_names_file_and_key(obj):
    o, _ = obj
    with h5py.File(o.folder / "calibration.h5", "a") as f:
        del f["H_NP3_from_NP5"]
    with pytest.raises(BadInputError) as e:
        o.camera_pose(3, 0)
    msg = str(e.value)
    assert str(o.folder / "calibration.h5") in msg and "H_NP3_from_NP5" in msg
    with h5py.File(o.folder / "poses" / "NP5_3_pose.h5", "a") as f:
        del f["H_table_from_reference_camera"]
    with pytest.raises(BadInputError) as e:
        o.camera_pose(1, 3)
    assert "NP5_3_pose.h5" in str(e.value) and "H_table_from_reference_camera" in str(e.value)


def test_nan_in_pose(obj):
    o, _ = obj
    path = o.folder / "poses" / "NP5_9_pose.h5"
    with h5py.File(path, "a") as f:
        H = f["H_table_from_reference_camera"][()]
        H[1, 3] = np.nan
        f["H_table_from_reference_camera"][...] = H
    with pytest.raises(BadInputError, match="NaN") as e:
        o.camera_position(1, 9)
    assert str(path) in str(e.value)


def test_corrupt_jpeg(obj):
    o, _ = obj
    views = o.views()
    data = views[0].image_path.read_bytes()
    views[0].image_path.write_bytes(data[: len(data) // 2])      # truncated
    views[1].image_path.write_bytes(b"this is not a jpeg")        # garbage
    for v in views[:2]:
        with pytest.raises(BadInputError, match="JPEG") as e:
            o.read_image(v)
        assert str(v.image_path) in str(e.value)
    views[2].image_path.unlink()
    with pytest.raises(BadInputError, match="missing"):
        o.read_image(views[2])


def test_mask_wrong_size_and_empty_mask(obj):
    o, _ = obj
    v0, v1 = o.views()[:2]
    v0.mask_path.write_bytes(encode_pbm(np.ones((24, 32), bool)))
    with pytest.raises(BadInputError, match="32x24 but its image is 64x48") as e:
        o.read_mask(v0)
    assert str(v0.mask_path) in str(e.value)
    v1.mask_path.write_bytes(encode_pbm(np.zeros((48, 64), bool)))
    with pytest.raises(BadInputError, match="empty") as e:
        o.read_view(v1)
    assert str(v1.mask_path) in str(e.value)
    specks = np.zeros((48, 64), bool)
    specks[5, 5] = specks[20:22, 30:32] = True
    with pytest.raises(BadInputError, match="specks"):
        o.object_box(specks)


def test_iter_views_skips_one_bad_view_and_goes_on(obj):
    o, truth = obj
    bad = o.views()[2]
    write_jpeg(bad.image_path, np.zeros((10, 10, 3), np.uint8))
    bad.image_path.write_bytes(bad.image_path.read_bytes()[:-300])  # corrupt
    with pytest.raises(BadInputError):
        list(o.iter_views())
    skip = SkipLog("view")
    recs = list(o.iter_views(skip=skip))
    assert skip.count == 1
    assert str(bad.image_path) in skip.examples[0]
    assert [r.view.angle for r in recs] == [a for a in truth["angles"] if a != bad.angle]
    for r in recs:
        assert r.box == truth["boxes"][(1, r.view.angle)]
