"""Locating an instance from its rays (pipeline/scene/location.py): the residual, the refusal of
rays that do not meet (a duplicated or moved object), and how the track planner reports it."""

import numpy as np
import pytest

from pipeline.evaluation.grid import population as P
from pipeline.scene.location import InconsistentRays, locate, locate_all, locate_rays, ray_distances
from pipeline.scene.rays import TrackError
from tests.pipeline.evaluation.grid.test_population import CX, FX, scene


def views_of(points, cams, rng):
    """Cameras ``cams`` (n, 2) each seeing one of ``points`` (cyclically): headings with jitter and
    the box-centre column a pinhole puts the point at."""
    pts = np.asarray(points, float)[np.arange(len(cams)) % len(points)]
    bearing = np.arctan2(pts[:, 1] - cams[:, 1], pts[:, 0] - cams[:, 0])
    heading = bearing + rng.uniform(-0.3, 0.3, len(cams))
    return heading, CX - FX * np.tan(bearing - heading)


def test_rays_through_one_point_locate_it_with_no_residual():
    rng = np.random.default_rng(0)
    cams = rng.uniform(-2, 2, (12, 2))
    heading, u = views_of([(0.3, 0.1)], cams, rng)
    loc = locate_rays(cams, heading, u, FX, CX, max_residual_m=0.01)
    np.testing.assert_allclose(loc.xy, [0.3, 0.1], atol=1e-9)
    assert loc.residual_m < 1e-9 and loc.n_rays == 12


def test_residual_is_the_rms_distance_of_the_rays():
    o = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
    d = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    np.testing.assert_allclose(ray_distances(o, d, [0.5, 0.0]), [0.5, 0.0, 0.5])


def test_a_duplicated_object_is_refused_with_its_residual():
    rng = np.random.default_rng(1)
    cams = rng.uniform(-3, 3, (40, 2))
    heading, u = views_of([(-2.0, 0.0), (2.0, 0.5)], cams, rng)   # two copies 4 m apart
    loc = locate_rays(cams, heading, u, FX, CX)                    # no limit: a point between them
    assert loc.residual_m > 0.5
    with pytest.raises(InconsistentRays, match=r"do not meet at one point: RMS distance \d+\.\d\d m") as e:
        locate_rays(cams, heading, u, FX, CX, max_residual_m=0.25)
    assert e.value.residual_m == pytest.approx(loc.residual_m) and e.value.n_rays == 40
    assert isinstance(e.value, TrackError)   # the planners' "no usable track of this scan"
    assert locate_rays(cams, heading, u, FX, CX, max_residual_m=loc.residual_m * 1.001).residual_m == loc.residual_m


def test_the_planner_excludes_the_inconsistent_scan_and_names_it():
    df, _ = scene()
    det = P.target_views(df, "t", 4)
    # in s2, every other view sees a second copy 3 m away
    s2 = (det["scan"] == "s2").to_numpy() & (np.arange(len(det)) % 2 == 0)
    second = np.array([3.1, -0.2])
    cam = det.loc[s2, ["cam_x", "cam_y"]].to_numpy(float)
    u = CX - FX * np.tan(np.arctan2(second[1] - cam[:, 1], second[0] - cam[:, 0]) - det.loc[s2, "heading"].to_numpy())
    det.loc[s2, "box_x0"], det.loc[s2, "box_x1"] = u - 10.0, u + 10.0
    intr, steps = {"s1": (FX, CX), "s2": (FX, CX)}, {"s1": 0.3, "s2": 0.3}
    tracks = P.plan_tracks(det, "t", 4, 5, 0, intr, steps, max_residual_m=0.25)
    assert {t.scan for t in tracks} == {"s1"}
    (r,) = tracks.refused
    assert r["scan"] == "s2" and r["target"] == "t" and r["residual_m"] > 0.25 and "s2: the " in r["reason"]
    # without a limit the planner averages the two copies, as it used to
    assert {t.scan for t in P.plan_tracks(det, "t", 4, 5, 0, intr, steps)} == {"s1", "s2"}
    with pytest.raises(TrackError, match="s2: the .* do not meet"):
        P.plan_tracks(det[det["scan"] == "s2"], "t", 4, 5, 0, intr, steps, max_residual_m=0.25)
    assert locate(det[det["scan"] == "s1"], FX, CX, 0.25).xy == pytest.approx([0.1, -0.2])
    # the one locate over every instance of a scan: the located ones and a record per refusal
    views = [("t", det[det["scan"] == "s1"]), ("copies", det[det["scan"] == "s2"]), ("one", det.iloc[:1])]
    found, refused = locate_all(views, FX, CX, 0.25, "scan")
    assert list(found) == ["t"] and found["t"].xy == pytest.approx([0.1, -0.2])
    by = {r["instance"]: r for r in refused}
    assert by["copies"]["residual_m"] > 0.25 and by["copies"]["scan"] == "scan" and by["one"]["residual_m"] is None
    # a mapping of arrays (a scan's boxes) is located as the table it holds (to the last bits,
    # which follow the memory layout)
    d = det[det["scan"] == "s1"]
    cols = {k: d[k].to_numpy(float) for k in ("cam_x", "cam_y", "heading", "box_x0", "box_x1")}
    np.testing.assert_allclose(locate(cols, FX, CX).xy, found["t"].xy, rtol=0, atol=1e-12)
