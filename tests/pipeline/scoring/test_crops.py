"""Crop geometry and normalisation (pipeline.scoring.crops): the one policy BigBIRD and AVD share."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.scoring.crops import CropPolicy, crop_box, extract, to_tensor


@settings(max_examples=200, deadline=None)
@given(x0=st.integers(-50, 500), y0=st.integers(-50, 500), w=st.integers(1, 400), h=st.integers(1, 400),
       margin=st.floats(0.0, 1.0))
def test_square_crop_is_centred_contains_the_box_and_has_the_policy_side(x0, y0, w, h, margin):
    cx0, cy0, cx1, cy1 = crop_box((x0, y0, x0 + w, y0 + h), margin, square=True)
    side = cx1 - cx0
    assert cy1 - cy0 == side
    assert side == max(1, round(max(w, h) * (1 + 2 * margin)))
    # Centred on the box centre to within half a pixel.
    assert abs((cx0 + cx1) / 2 - (x0 + w / 2)) <= 0.5
    assert abs((cy0 + cy1) / 2 - (y0 + h / 2)) <= 0.5
    # The margin is never negative: the crop holds the whole box (up to the half-pixel centring).
    assert cx0 <= x0 + 0.5 and cx1 >= x0 + w - 0.5 and cy0 <= y0 + 0.5 and cy1 >= y0 + h - 0.5


def test_rectangular_crop_moves_each_side_by_the_margin_of_the_longer_side():
    assert crop_box((10, 20, 110, 60), 0.1, square=False) == (0, 10, 120, 70)
    assert crop_box((10, 20, 110, 60), 0.0, square=False) == (10, 20, 110, 60)


def test_degenerate_boxes_are_errors():
    for box in [(5, 5, 5, 10), (5, 5, 10, 4)]:
        with pytest.raises(ValueError, match="degenerate box"):
            crop_box(box, 0.1, True)


def _ramp(h=60, w=80):
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 3 % 256, y * 4 % 256, (x + y) % 256], -1).astype(np.uint8)


def test_inside_crop_at_native_size_is_the_exact_pixels():
    img = _ramp()
    out = extract(img, (10, 5, 42, 37), 32)
    np.testing.assert_array_equal(out, img[5:37, 10:42])


def test_padding_outside_the_image_follows_the_pad_mode():
    img = _ramp()
    # 10 px left of the image and 6 above; native size, so no resampling.
    cb = (-10, -6, 22, 26)
    mean = extract(img, cb, 32, pad="mean", fill=(1, 2, 3))
    assert (mean[:6] == (1, 2, 3)).all() and (mean[:, :10] == (1, 2, 3)).all()
    np.testing.assert_array_equal(mean[6:, 10:], img[0:26, 0:22])
    edge = extract(img, cb, 32, pad="edge")
    np.testing.assert_array_equal(edge[6:, 0], img[0:26, 0])   # left border replicated
    np.testing.assert_array_equal(edge[0, 10:], img[0, 0:22])                          # top border replicated
    refl = extract(img, cb, 32, pad="reflect")
    np.testing.assert_array_equal(refl[6:, 9], img[0:26, 1])                           # reflect-101
    with pytest.raises(ValueError, match="does not overlap"):
        extract(img, (100, 100, 120, 120), 8)


def test_resize_keeps_a_flat_image_flat_and_gives_the_output_size():
    img = np.full((300, 200, 3), (40, 90, 200), np.uint8)
    for interp in ("auto", "area", "linear", "cubic"):
        out = extract(img, (20, 30, 180, 190), 64, interpolation=interp)
        assert out.shape == (64, 64, 3) and out.dtype == np.uint8
        assert (out == (40, 90, 200)).all()
    # Upscaling a 2-px checker must not alias into something flat.
    small = np.zeros((4, 4, 3), np.uint8)
    small[::2, ::2] = 255
    assert extract(small, (0, 0, 4, 4), 16).std() > 20


def test_policy_crop_matches_the_pieces_and_reports_the_crop_box():
    img = _ramp(120, 160)
    pol = CropPolicy(margin=0.25, square=True, size=48)
    crop, cb = pol.crop(img, (40, 30, 80, 90))
    assert cb == crop_box((40, 30, 80, 90), 0.25, True)
    np.testing.assert_array_equal(crop, extract(img, cb, 48, fill=pol.fill_value))
    # Mean padding becomes a zero network input (no signal from outside the image).
    pol = CropPolicy(margin=2.0, size=32)
    crop, cb = pol.crop(np.full((40, 40, 3), 255, np.uint8), (0, 0, 10, 10))
    t = pol.to_tensor(crop)
    assert cb[0] < 0 and cb[1] < 0
    assert t.shape == (1, 3, 32, 32)
    assert float(t[0, :, 0, 0].abs().max()) < 0.02


def test_to_tensor_normalises_per_channel():
    mean, std = (0.5, 0.25, 0.75), (0.5, 0.25, 0.125)
    img = np.zeros((1, 2, 2, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 255, 0, 51
    t = to_tensor(img, mean, std).numpy()
    assert t.shape == (1, 3, 2, 2)
    np.testing.assert_allclose(t[0, 0], (1.0 - 0.5) / 0.5, atol=1e-6)
    np.testing.assert_allclose(t[0, 1], (0.0 - 0.25) / 0.25, atol=1e-6)
    np.testing.assert_allclose(t[0, 2], (0.2 - 0.75) / 0.125, atol=1e-5)
    with pytest.raises(ValueError, match="uint8"):
        to_tensor(np.zeros((1, 2, 2, 3), np.float32))


def test_policy_comes_from_the_config_sections(tmp_config):
    cfg = tmp_config({"features": {"margin": 0.3, "square": False, "pad": "edge"}, "classifier": {"input_size": 96}})
    pol = CropPolicy.from_config(cfg)
    assert (pol.margin, pol.square, pol.size, pol.pad) == (0.3, False, 96, "edge")
    assert pol.mean == tuple(cfg.classifier.mean) and math.isclose(pol.std[0], 0.229)
    with pytest.raises(ValueError, match="pad"):
        CropPolicy(pad="wrap")
