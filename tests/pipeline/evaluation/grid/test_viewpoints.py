"""Grid points (pipeline/scene/viewpoints.py) and their use by the track builder: stops from
the move graph's rotate edges, the grid step off them, one view per stop; and on the synthetic
scans they change nothing (the same partition, grid step and tracks as the position cells)."""
import dataclasses

import numpy as np
import pytest

from pipeline.evaluation.grid.track import select_tracks
from pipeline.scene.rays import facing_error, grid_step
from pipeline.scene.viewpoints import cluster_positions, grid_points, has_rotate_edges, scan_grid_points
from tests.pipeline.evaluation.grid.test_track import grid_world


def ring_moves(rings: dict[str, list[str]]) -> dict[str, dict[str, str]]:
    """Move graph of turn-on-the-spot rings: ccw to the next name, cw to the previous."""
    out = {}
    for names in rings.values():
        for i, n in enumerate(names):
            out[n] = {"rotate_ccw": names[(i + 1) % len(names)], "rotate_cw": names[i - 1], "forward": ""}
    return out


def test_rotate_edges_make_the_grid_points():
    moves = ring_moves({"a": ["b1.jpg", "b2.jpg", "b3.jpg"], "b": ["a1.jpg", "a3.jpg", "a2.jpg"]})
    moves["a1.jpg"]["forward"] = "b1.jpg"           # translations join nothing
    moves["z.jpg"] = {"rotate_ccw": "", "rotate_cw": "gone.jpg"}   # no edge inside the scan
    g = grid_points(moves)
    assert g == {"a1.jpg": 0, "a2.jpg": 0, "a3.jpg": 0, "b1.jpg": 1, "b2.jpg": 1, "b3.jpg": 1, "z.jpg": 2}
    # one-way edges are enough (a ring written with ccw pointers only)
    only_ccw = {n: {"rotate_ccw": m["rotate_ccw"]} for n, m in moves.items()}
    assert grid_points(only_ccw) == g
    assert has_rotate_edges(moves) and not has_rotate_edges({"x.jpg": {"rotate_cw": ""}})


def test_without_rotate_edges_close_centres_are_chained():
    xy = np.array([[0.0, 0.0], [0.3, 0.0], [0.02, 0.01], [0.04, 0.02], [0.31, 0.015]])
    np.testing.assert_array_equal(cluster_positions(xy, 0.1), [0, 1, 0, 0, 1])
    names = [f"{i}.jpg" for i in range(5)]
    assert scan_grid_points({n: {} for n in names}, dict(zip(names, xy))) == dict(zip(names, [0, 1, 0, 0, 1]))


def jittered_world(spread=0.02, seed=0, extent=0.9):
    """grid_world with the headings of one stop ``spread`` m apart, as in real reconstructions."""
    cam, heading, obj = grid_world(headings=12, extent=extent)
    gid = np.repeat(np.arange(len(cam) // 12), 12)
    cam = cam + np.random.default_rng(seed).normal(0.0, spread / 2, cam.shape)
    return cam, heading, obj, gid


def test_grid_step_and_tracks_on_jittered_stops_need_the_grid_points():
    cam, heading, obj, gid = jittered_world()
    assert grid_step(cam) < 0.03                     # the spread of one stop, not the grid
    assert grid_step(cam, gid) == pytest.approx(0.3, abs=0.01)
    with pytest.raises(ValueError, match="one id per camera"):
        grid_step(cam, gid[:-1])
    err = facing_error(cam, heading, obj)
    new = select_tracks(cam, obj, err, 9, 6, seed=1, grid_step=grid_step(cam, gid), grid_id=gid)
    old = select_tracks(cam, obj, err, 9, 6, seed=1, grid_step=grid_step(cam))
    assert len(new) == 6 and all(len(set(gid[t.index])) == 9 for t in new)
    assert sum(9 - len(set(gid[t.index])) for t in old) > 0   # views on a stop already used


@pytest.fixture(scope="module")
def synthetic_scan(tmp_path_factory):
    from loaders.avd import AVDScan
    from loaders.synthetic.avd_writer import write_avd_scan
    from tests.loaders.synthetic.test_synthetic_avd import SCAN, SEED, TINY

    root = tmp_path_factory.mktemp("avd")
    write_avd_scan(root, dataclasses.replace(TINY, grid_step_m=0.3, room_size_m=(2.7, 2.4)), SCAN, SEED)
    return AVDScan(root, SCAN)


def test_on_synthetic_scans_the_grid_points_change_nothing(synthetic_scan):
    """The synthetic default's tracks must not move: there a stop's headings share one centre, so
    the position cells and the move graph's stops are the same partition, the grid step is the same
    float and select_tracks picks the same views."""
    s = synthetic_scan
    names = sorted(s.images)
    cam = np.array([s.images[n].position for n in names])
    heading = np.array([s.images[n].heading for n in names])
    g = s.grid_points()
    gid = np.array([g[n] for n in names])
    assert len(set(gid)) == len(names) // 12 and set(np.bincount(gid)) == {12}
    step = grid_step(cam)
    assert grid_step(cam, gid) == step
    cells = np.round(cam / (step / 2)).astype(np.int64)
    assert len({tuple(c) for c in cells}) == len(set(gid))
    assert all(len({tuple(c) for c in cells[gid == k]}) == 1 for k in set(gid))
    for obj in ([1.2, 1.1], [0.5, 1.6], [2.0, 0.4]):
        obj = np.array(obj)
        err = facing_error(cam, heading, obj)
        old = select_tracks(cam, obj, err, 5, 4, seed=2, grid_step=step)
        new = select_tracks(cam, obj, err, 5, 4, seed=2, grid_step=grid_step(cam, gid), grid_id=gid)
        assert [t.index.tolist() for t in old] == [t.index.tolist() for t in new]
