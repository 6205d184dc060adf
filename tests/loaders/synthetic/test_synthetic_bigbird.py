"""The BigBIRD writer, read back with the real-format reader."""
from __future__ import annotations

import dataclasses

import cv2
import h5py
import numpy as np
import pytest

from loaders.bigbird import BigBirdObject, list_objects
from loaders.pbm import read_pbm
from loaders.synthetic.bigbird_writer import (CAMERAS, angles, make_rig, render_view, rz4,
                                              write_bigbird_object)
from loaders.synthetic.nuisance import RigNuisance, mask_errors, object_pose, sensor
from loaders.synthetic.objects import make_instance
from loaders.synthetic.render import Camera, project
from pipeline.infra.config import SyntheticDataConfig

NAME = "aunt_jemima_original_syrup"
TINY = dataclasses.replace(SyntheticDataConfig(), bigbird_width=320, bigbird_height=256,
                           angle_step_deg=60, bigbird_cameras=(1, 5), write_depth=True)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("bigbird")
    write_bigbird_object(root, NAME, TINY, seed=3)
    return root


def test_folder_layout_is_the_real_one(written):
    folder = written / NAME
    assert list_objects(written) == [NAME]
    names = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}
    for a in angles(60):
        assert f"poses/NP5_{a}_pose.h5" in names
        for c in (1, 5):
            assert {f"NP{c}_{a}.jpg", f"masks/NP{c}_{a}_mask.pbm", f"NP{c}_{a}.h5"} <= names
        assert f"NP2_{a}.jpg" not in names  # only the configured cameras are rendered
    assert "calibration.h5" in names and "poses/turntable.h5" in names
    assert not [n for n in names if n.startswith(".")]  # no temporary files left behind


def test_calibration_keys_shapes_and_dtypes(written):
    with h5py.File(written / NAME / "calibration.h5", "r") as f:
        for c in CAMERAS:
            for key, shape in ((f"H_NP{c}_from_NP5", (4, 4)), (f"H_NP{c}_ir_from_NP5", (4, 4)),
                               (f"H_N{c}_from_NP5", (4, 4)), (f"NP{c}_rgb_K", (3, 3)),
                               (f"NP{c}_depth_K", (3, 3)), (f"NP{c}_ir_K", (3, 3)), (f"N{c}_rgb_K", (3, 3)),
                               (f"NP{c}_rgb_d", (5,)), (f"NP{c}_ir_d", (5,)),
                               (f"NP{c}_ir_depth_scale", (1,)), (f"NP{c}_ir_depth_bias", (1,))):
                assert f[key].shape == shape, key
                assert f[key].dtype == np.float64, key
        assert np.array_equal(f["H_NP5_from_NP5"][()], np.eye(4))
    with h5py.File(written / NAME / "poses" / "NP5_120_pose.h5", "r") as f:
        assert f["H_table_from_reference_camera"].shape == (4, 4)
        assert f["board_frame_offset"].shape == (3,)


def test_poses_read_back_equal_the_generator_and_turn_about_z(written):
    obj = BigBirdObject(written / NAME)
    rig = make_rig(320, 256)
    for a in angles(60):
        assert np.allclose(obj.reference_pose(a), rz4(a) @ obj.reference_pose(0), atol=1e-9)
        for c in (1, 5):
            assert np.abs(obj.camera_pose(c, a) - rig.camera_pose(c, a)).max() < 1e-6
        assert np.allclose(obj.intrinsics(1), rig.rgb_K[1])
    # The rig: NP1 lowest (side view), NP5 highest (near top-down), ~0.6-0.7 m away.
    pos = {c: obj.camera_position(c, 0) for c in CAMERAS}
    heights = [pos[c][2] for c in CAMERAS]
    assert heights == sorted(heights)
    elev1 = np.arctan2(pos[1][2] - 0.12, np.hypot(*pos[1][:2]))
    elev5 = np.arctan2(pos[5][2] - 0.12, np.hypot(*pos[5][:2]))
    assert 0.1 <= elev1 <= 0.2 and elev5 > 1.2
    for c in CAMERAS:
        assert 0.6 <= np.linalg.norm(pos[c] - [0, 0, 0.12]) <= 0.7


def test_images_and_masks_are_rendered_with_the_file_poses(written):
    """Project the object's corners (placed as the writer placed them: off-centre, wobbling) with
    the *reader's* K and pose: the mask's box must match up to the configured mask error."""
    obj = BigBirdObject(written / NAME)
    inst = make_instance(NAME, 3)
    pts0 = np.concatenate([f.vertices for f in inst.faces])
    nz = RigNuisance.from_config(TINY)
    tol = 1.5 + nz.mask_error_px + 1  # + the ragged edge
    views = obj.views(cameras=(1, 5))
    assert [(v.camera, v.angle) for v in views] == [(c, a) for c in (1, 5) for a in angles(60)]
    for rec in obj.iter_views(cameras=(1, 5)):
        assert rec.image.shape == (256, 320, 3) and rec.mask.shape == (256, 320)
        R, t = object_pose(nz, 3, NAME, rec.view.angle)
        pts = pts0 @ R.T + t
        cam = Camera.from_pose(rec.pose, obj.intrinsics(rec.view.camera), 320, 256)
        uv = project(cam, pts)
        x0, y0, x1, y1 = rec.box
        assert abs(x0 - uv[:, 0].min()) <= tol and abs(x1 - 1 - uv[:, 0].max()) <= tol
        assert abs(y0 - uv[:, 1].min()) <= tol and abs(y1 - 1 - uv[:, 1].max()) <= tol
        # The object's pixels differ from the bright backdrop.
        assert rec.image[rec.mask].mean() < 200 < rec.image[:5].mean()


def test_mask_polarity_header_and_specks(written):
    path = written / NAME / "masks" / "NP1_60_mask.pbm"
    data = path.read_bytes()
    assert data.startswith(b"P4 320 256\n") and len(data) == len(b"P4 320 256\n") + 320 * 256 // 8
    mask = read_pbm(path)  # True = bit 1 = black
    nz = RigNuisance.from_config(TINY)
    _, clean = render_view(make_instance(NAME, 3), make_rig(320, 256), 1, 60, object_pose(nz, 3, NAME, 60))
    # Object = bit 1: the mask covers the object but for a boundary band of the configured error.
    k = np.ones((2 * nz.mask_error_px + 3,) * 2, np.uint8)
    inner = cv2.erode(clean.astype(np.uint8), k).astype(bool)
    near = cv2.dilate(clean.astype(np.uint8), k).astype(bool)
    assert mask[inner].all()
    extra = mask & ~near
    assert 0 < extra.sum() < 50  # a few spurious specks, as in real masks
    obj = BigBirdObject(written / NAME)
    ys, xs = np.nonzero(clean)
    # The reader's cleanup drops the specks (its opening may trim a one-pixel sliver at an edge);
    # the box is off by at most the mask error + the ragged edge + that sliver.
    box = np.array(obj.object_box(mask))
    assert np.abs(box - [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]).max() <= nz.mask_error_px + 2


def test_depth_maps_are_in_the_ir_camera_in_tenths_of_mm(written):
    with h5py.File(written / NAME / "NP1_0.h5", "r") as f:
        d = f["depth"][()]
    assert d.dtype == np.uint16 and d.shape == (480, 640)
    z = d[d > 0] * 1e-4
    assert 0.45 < z.min() < z.max() < 0.9  # object and turntable ~0.6 m away, backdrop invalid
    assert (d == 0).mean() > 0.3


def test_views_from_different_sides_show_different_faces():
    rig, inst = make_rig(320, 256), make_instance(NAME, 0)
    front, m0 = render_view(inst, rig, 1, 0)
    back, _ = render_view(inst, rig, 1, 180)  # a symmetric silhouette: compare the same pixels
    assert np.abs(front[m0].astype(float).mean(0) - back[m0].astype(float).mean(0)).max() > 10


def test_deterministic_for_a_seed(tmp_path):
    small = dataclasses.replace(TINY, angle_step_deg=120, bigbird_cameras=(1,), write_depth=False)
    for seed, sub in ((3, "a"), (3, "b"), (4, "c")):
        write_bigbird_object(tmp_path / sub, NAME, small, seed=seed)
    files = [p.relative_to(tmp_path / "a" / NAME) for p in (tmp_path / "a" / NAME).rglob("*") if p.is_file()]
    assert files
    for rel in files:
        assert (tmp_path / "a" / NAME / rel).read_bytes() == (tmp_path / "b" / NAME / rel).read_bytes(), rel
    jpg = "NP1_0.jpg"
    assert (tmp_path / "a" / NAME / jpg).read_bytes() != (tmp_path / "c" / NAME / jpg).read_bytes()


def test_sensor_noise_has_the_configured_signal_dependent_std():
    nz = RigNuisance(read_noise=2.0, shot_noise=0.1)
    for level in (40, 200):
        flat = np.full((256, 256, 3), level, np.uint8)
        out = sensor(flat, nz, 0, np.random.default_rng(1)).astype(float)
        want = np.sqrt(2.0 ** 2 + 0.1 * level)
        assert out.mean() == pytest.approx(level, abs=0.3)
        assert out.std() == pytest.approx(want, rel=0.08)  # 8-bit rounding adds ~1/12 variance


def test_exposure_and_white_balance_jitter_scale_channels():
    nz = RigNuisance(exposure=0.1, white_balance=0.05)
    flat = np.full((8, 8, 3), 100, np.uint8)
    gains = np.array([sensor(flat, nz, 0, np.random.default_rng(i))[0, 0] / 100.0 for i in range(200)])
    assert 0.08 < np.log(gains).mean(1).std() < 0.13      # exposure: common to the channels
    assert np.log(gains).std(1).mean() > 0.02             # white balance: differs per channel
    assert sensor(flat, RigNuisance(), 0, np.random.default_rng(0)).tolist() == flat.tolist()


def test_mask_errors_stay_within_the_configured_band():
    mask = np.zeros((60, 80), bool)
    mask[20:40, 25:55] = True
    k = np.ones((7, 7), np.uint8)  # px = 2, + 1 for the ragged edge
    for i in range(20):
        out = mask_errors(mask, 2, np.random.default_rng(i))
        assert out[cv2.erode(mask.astype(np.uint8), k).astype(bool)].all()
        assert not out[~cv2.dilate(mask.astype(np.uint8), k).astype(bool)].any()
    assert (mask_errors(mask, 0, np.random.default_rng(0)) == mask).all()
    assert any((mask_errors(mask, 2, np.random.default_rng(i)) != mask).any() for i in range(3))


def test_object_is_decentred_once_and_wobbles_per_angle():
    nz = RigNuisance(decentre_m=0.006)
    (R0, t0), (R1, t1) = object_pose(nz, 0, NAME, 0), object_pose(nz, 0, NAME, 90)
    assert np.linalg.norm(t0) == pytest.approx(0.006) and np.allclose(t0, t1) and np.allclose(R0, np.eye(3))
    nz = dataclasses.replace(nz, wobble_deg=1.0, wobble_m=0.001)
    (_, a), (_, b) = object_pose(nz, 0, NAME, 0), object_pose(nz, 0, NAME, 3)
    assert 0 < np.linalg.norm(a - b) < 0.01
    assert np.allclose(object_pose(nz, 0, NAME, 3)[1], b)  # the same for every camera at an angle


def test_sensor_noise_in_bands_equals_the_whole_image_arithmetic():
    # The noise is added in bands of rows; each pixel must get exactly the whole-image result
    # (the formula literally, on a height that is not a multiple of the band).
    import cv2

    from loaders.synthetic.nuisance import SENSOR_ROWS, _normal_bank

    nz = RigNuisance(read_noise=1.5, shot_noise=0.04, exposure=0.04, white_balance=0.02)
    rgb = np.random.default_rng(5).integers(0, 256, (3 * SENSOR_ROWS + 7, 90, 3), dtype=np.uint8)
    got = sensor(rgb, nz, 11, np.random.default_rng(2))
    rng = np.random.default_rng(2)
    gain = np.exp(rng.normal(0.0, nz.exposure) + rng.normal(0.0, nz.white_balance, 3))
    levels = np.arange(256, dtype=np.float32)
    lut = np.clip(levels[:, None] * gain[None, :].astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
    img = cv2.LUT(rgb, lut.reshape(256, 1, 3))
    sd = cv2.LUT(img, np.sqrt(nz.read_noise ** 2 + nz.shot_noise * levels).astype(np.float32))
    off = int(rng.integers(0, img.size))
    noise = cv2.multiply(_normal_bank(11, img.size)[off:off + img.size].reshape(img.shape), sd)
    want = cv2.add(img, noise, dtype=cv2.CV_8U)
    assert not np.array_equal(want, img)
    np.testing.assert_array_equal(got, want)
