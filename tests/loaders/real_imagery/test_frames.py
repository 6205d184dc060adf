"""Frames of the real-imagery source: bearing -> nearest held-out view (never a training view),
the pasted view's box size, the sensor window; and on the real data, what the writer put in the
frames and annotations."""
from __future__ import annotations

import numpy as np
import pytest

from loaders.real_imagery.frames import (
    heldout_angles,
    mask_bbox,
    nearest_view,
    object_bearing_deg,
    render_frame,
    resampled_view,
)
from loaders.real_imagery.pairing import pair_scan
from pipeline.method.geometry import relative_inputs


def test_bearing_is_the_gp_input_angle():
    cam = np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, -1.0]])
    obj, yaw = np.array([0.0, 0.0]), 30.0
    u = relative_inputs(cam, obj, np.radians(yaw))
    got = object_bearing_deg(cam, obj, yaw)
    np.testing.assert_allclose(got, np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360)
    np.testing.assert_allclose(got, [330.0, 60.0, 195.0])


def test_nearest_heldout_view_is_never_a_training_view():
    angles = list(range(0, 360, 5))
    held = heldout_angles(angles, 10)
    assert held[:3] == [5, 15, 25] and all(a % 10 for a in held)
    for b in np.linspace(0, 360, 721):
        a = nearest_view(b, held)
        assert a % 10 == 5
        assert abs((a - b + 180) % 360 - 180) <= 5.0 + 1e-9
    assert nearest_view(359.0, held) == 355 and nearest_view(1.0, held) == 5
    assert nearest_view(0.0, held) == 5   # tie between 355 and 5: the smaller angle
    held.remove(15)                       # a missing held-out view: the next nearest
    assert nearest_view(15.0, held) == 5


def _disc(w=40, h=20):
    img = np.zeros((128, 128, 3), np.uint8)
    img[54:54 + h, 44:44 + w] = 200
    return img, img[:, :, 0] > 0


@pytest.mark.parametrize("bw,bh", [(10, 7), (80, 160), (300, 120)])
def test_pasted_view_fills_the_real_box(bw, bh):
    rgb, mask = _disc()
    patch, (dx, dy) = resampled_view(rgb, mask, bw, bh)
    inner = patch[dy:dy + bh, dx:dx + bw, 0]
    assert inner.mean() > 150          # the object covers the box
    box = (500, 300, 500 + bw, 300 + bh)
    frame = render_frame((1920, 1080), [(rgb, mask, box)], 0.0, 0.0, np.random.default_rng(0))
    x0, y0, x1, y1 = mask_bbox(frame[:, :, 0] > 100)
    assert abs(x0 - box[0]) <= 1 and abs(y0 - box[1]) <= 1 and abs(x1 - box[2]) <= 1 and abs(y1 - box[3]) <= 1


def test_sensor_model_acts_near_the_box_only():
    rgb, mask = _disc()
    box = (100, 100, 140, 120)
    frame = render_frame((640, 360), [(rgb, mask, box)], 5.0, 1.0, np.random.default_rng(0))
    assert frame[60:160, 60:180].std() > 1.0      # noise in the window
    assert not frame[300:, 400:].any()           # black far away


def test_objects_go_in_by_their_mask_in_the_given_order():
    """A photograph's ground (grey here, as COIL's near-black) never reaches the frame, and an
    object pasted later (the nearer) covers an earlier one only where its own silhouette lies."""
    far = np.full((128, 128, 3), 30, np.uint8)          # a grey ground around a red square
    far[40:88, 40:88] = (220, 0, 0)
    near = np.full((128, 128, 3), 30, np.uint8)         # a green bar, its ground over the red one's box
    near[20:108, 60:68] = (0, 220, 0)
    fm, nm = far[:, :, 0] > 100, near[:, :, 1] > 100
    fbox, nbox = (100, 100, 148, 148), (140, 90, 148, 178)
    frame = render_frame((320, 240), [(far, fm, fbox), (near, nm, nbox)], 0.0, 0.0, np.random.default_rng(0))
    assert (frame[100:148, 100:140] == (220, 0, 0)).all()    # the far object whole beside the near one
    assert (frame[90:178, 140:148] == (0, 220, 0)).all()     # the near one on top where they overlap
    ground = np.ones(frame.shape[:2], bool)
    ground[100:148, 100:148] = ground[90:178, 140:148] = False
    assert not frame[ground].any()                           # no pixel of either ground: the frame's black
    swapped = render_frame((320, 240), [(near, nm, nbox), (far, fm, fbox)], 0.0, 0.0, np.random.default_rng(0))
    assert (swapped[100:148, 140:148] == (220, 0, 0)).all()  # the order decides who covers whom


def test_pairing_is_seeded_distinct_and_drops_extras():
    loc = {f"inst{i}": (np.array([i, 0.0]), 0.01) for i in range(6)}
    a, left = pair_scan("S", loc, [2, 3, 4, 5], 0, 0)
    b, _ = pair_scan("S", loc, [2, 3, 4, 5], 0, 0)
    assert a == b and len(a) == 4 and len(left) == 2
    assert sorted(p.object_id for p in a) == [2, 3, 4, 5]
    c, _ = pair_scan("S", loc, [2, 3, 4, 5], 1, 0)
    assert [(p.instance, p.object_id) for p in c] != [(p.instance, p.object_id) for p in a]
    assert all(0 <= p.yaw_deg < 360 for p in a)
