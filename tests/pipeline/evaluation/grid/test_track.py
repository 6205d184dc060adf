import numpy as np
import pytest

from pipeline.evaluation.grid.track import select_tracks
from pipeline.scene.rays import TrackError, bearing_rays, facing_error, intersect_rays


def project_cx(cam_xy, heading, obj_xy, fx, cx):
    """Column of the object in each camera (pinhole, no roll): right of centre = clockwise."""
    rel = obj_xy - cam_xy
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - heading
    return cx - fx * np.tan(ang)


def ring(n, radius, centre, rng, jitter=0.0):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    p = centre + radius * np.stack([np.cos(th), np.sin(th)], 1)
    rel = centre - p
    heading = np.arctan2(rel[:, 1], rel[:, 0]) + rng.uniform(-jitter, jitter, n)
    return p, heading


def test_rays_intersect_at_the_object():
    rng = np.random.default_rng(0)
    obj = np.array([1.3, -0.4])
    cam, heading = ring(9, 1.2, obj, rng, jitter=0.4)
    fx, cx = 500.0, 320.0
    u = project_cx(cam, heading, obj, fx, cx)
    o, d = bearing_rays(cam, heading, u, fx, cx)
    np.testing.assert_allclose(intersect_rays(o, d), obj, atol=1e-9)


def test_intersection_with_pixel_noise_is_close():
    rng = np.random.default_rng(1)
    obj = np.array([0.0, 2.0])
    cam, heading = ring(12, 1.5, obj, rng, jitter=0.3)
    u = project_cx(cam, heading, obj, 500.0, 320.0) + rng.normal(0, 2.0, 12)
    est = intersect_rays(*bearing_rays(cam, heading, u, 500.0, 320.0))
    assert np.linalg.norm(est - obj) < 0.03


def test_parallel_rays_are_rejected():
    o = np.array([[0.0, 0.0], [0.0, 1.0]])
    d = np.array([[1.0, 0.0], [1.0, 0.0]])
    with pytest.raises(TrackError, match="parallel"):
        intersect_rays(o, d)
    with pytest.raises(TrackError, match="at least 2"):
        intersect_rays(o[:1], d[:1])


def test_select_tracks_too_few_views():
    cam = np.array([[1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(TrackError, match="only 2 distinct viewpoints"):
        select_tracks(cam, np.zeros(2), np.zeros(2), 5, 2, seed=0)


def grid_world(step=0.3, extent=1.5, headings=4, obj=(0.1, -0.2)):
    """AVD-like capture: a square grid of points, several headings each, the object inside."""
    g = np.arange(-extent, extent + 1e-9, step)
    pts = np.array([(x, y) for x in g for y in g if np.hypot(x - obj[0], y - obj[1]) > 0.4])
    cam = np.repeat(pts, headings, axis=0)
    heading = np.tile(np.arange(headings) * 2 * np.pi / headings, len(pts))
    return cam, heading, np.asarray(obj)


def test_grid_step_is_read_off_the_positions():
    from pipeline.scene.rays import grid_step
    for step in (0.3, 0.5):
        cam, _, _ = grid_world(step=step)
        assert grid_step(cam) == pytest.approx(step)
    with pytest.raises(TrackError, match="grid step"):
        grid_step(np.zeros((4, 2)))


def test_tracks_are_distinct_see_the_target_and_are_deterministic():
    from pipeline.evaluation.grid.track import select_tracks
    cam, heading, obj = grid_world()
    err = facing_error(cam, heading, obj)
    seeing = err < np.radians(50)                     # the "views that see the target"
    cam, heading, err = cam[seeing], heading[seeing], err[seeing]
    tracks = select_tracks(cam, obj, err, 9, 8, seed=3, grid_step=0.3)
    assert len(tracks) == 8
    sets = {frozenset(t.index.tolist()) for t in tracks}
    assert len(sets) == 8                              # distinct view sets
    for t in tracks:
        assert len(t.index) == 9 and len(set(t.index.tolist())) == 9
        pos = np.round(cam[t.index], 6)
        assert len(np.unique(pos, axis=0)) == 9        # one view per grid point
        # Ordered along the direction of travel.
        unwrapped = np.unwrap(np.radians(t.bearing_deg)) * t.direction
        assert np.all(np.diff(unwrapped) > 0)
    assert {t.direction for t in tracks} == {1, -1}
    assert {t.distance for t in tracks} == {"near", "far"}
    again = select_tracks(cam, obj, err, 9, 8, seed=3, grid_step=0.3)
    assert [t.index.tolist() for t in again] == [t.index.tolist() for t in tracks]
    other = select_tracks(cam, obj, err, 9, 8, seed=4, grid_step=0.3)
    assert [t.index.tolist() for t in other] != [t.index.tolist() for t in tracks]


def test_few_viewpoints_give_fewer_tracks_or_a_named_error():
    from pipeline.evaluation.grid.track import select_tracks
    rng = np.random.default_rng(0)
    obj = np.zeros(2)
    cam, heading = ring(10, 1.0, obj, rng)
    err = facing_error(cam, heading, obj)
    # 10 viewpoints hold 10 distinct 9-view sets: 8 tracks fit; 9 viewpoints hold one.
    assert len(select_tracks(cam, obj, err, 9, 8, seed=0, grid_step=0.3)) == 8
    tracks = select_tracks(cam[:9], obj, err[:9], 9, 8, seed=0, grid_step=0.3)
    assert len(tracks) == 1
    with pytest.raises(TrackError, match="only 10 distinct viewpoints"):
        select_tracks(cam, obj, err, 11, 2, seed=0, grid_step=0.3)
