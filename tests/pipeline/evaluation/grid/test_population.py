"""The population grid (pipeline/evaluation/grid/population.py) on generated scenes: settings, object
location from box centres, tracks spread over scans, score gathering, per-cell noise, yaws."""
import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.grid import population as P
from pipeline.scene.rays import TrackError
from pipeline.infra.config import EvaluateConfig, RandomizedConfig
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models

FX, CX = 500.0, 320.0


def scene(scans=("s1", "s2"), obj=(0.1, -0.2), step=0.3, extent=1.5, n_s=3, D=4, seed=0):
    """AVD-like rows of one target: per scan a capture grid, cameras facing the object (with
    jitter), box centres from a pinhole projection; a deterministic pass and ``n_s`` dropout
    passes per view with random scores (D components). Returns (rows, scores)."""
    rng = np.random.default_rng(seed)
    rows = []
    g = np.arange(-extent, extent + 1e-9, step)
    for scan in scans:
        for i, (x, y) in enumerate((x, y) for x in g for y in g if math.hypot(x - obj[0], y - obj[1]) > 0.4):
            heading = math.atan2(obj[1] - y, obj[0] - x) + rng.uniform(-0.2, 0.2)
            ang = math.atan2(obj[1] - y, obj[0] - x) - heading
            u = CX - FX * math.tan(ang)
            for p in range(-1, n_s):
                rows.append({"scan": scan, "image": f"{scan}_{i:03d}.jpg", "instance": "t", "difficulty": 1,
                             "pass": p, "cam_x": x, "cam_y": y, "heading": heading,
                             "box_x0": u - 10.0, "box_x1": u + 10.0})
    df = pd.DataFrame(rows)
    return df, rng.random((len(df), D))


def test_settings_are_the_biased_experiment_and_one_randomized_per_sigma():
    ev = EvaluateConfig()
    s = P.population_settings(ev)
    assert [x.experiment for x in s] == ["biased"] + ["randomized"] * len(ev.randomized.sigmas_m)
    assert s[0].realizations == 1 and s[0].n_x == ev.biased.n_loc_samples
    assert [x.sigma for x in s[1:]] == list(ev.randomized.sigmas_m)
    assert len({x.label for x in s}) == len(s)
    assert P.setting_label(0.001, (0.0, 0.25)) != P.setting_label(0.004, (0.0, 0.25))   # every digit kept
    only = dataclasses.replace(ev, experiments=("randomized",))
    assert {x.experiment for x in P.population_settings(only)} == {"randomized"}
    twice = dataclasses.replace(ev, randomized=RandomizedConfig(sigmas_m=(0.1, 0.1)))
    with pytest.raises(ValueError, match="same sigma twice"):
        P.population_settings(twice)


def test_the_object_is_located_from_its_box_centres():
    df, _ = scene(scans=("s1",))
    det = P.target_views(df, "t", max_difficulty=4)
    assert (det["pass"] == -1).all() and det["image"].is_unique
    np.testing.assert_allclose(P.locate(det, FX, CX).xy, [0.1, -0.2], atol=1e-9)


def test_tracks_alternate_over_the_scans_and_hold_distinct_views():
    df, _ = scene()
    det = P.target_views(df, "t", 4)
    intr = {"s1": (FX, CX), "s2": (FX, CX)}
    steps = {"s1": 0.3, "s2": 0.3}
    tracks = P.plan_tracks(det, "t", 4, 5, seed=0, intrinsics=intr, grid_steps=steps)
    assert [t.track for t in tracks] == [0, 1, 2, 3]
    assert sorted(t.scan for t in tracks) == ["s1", "s1", "s2", "s2"]
    for t in tracks:
        assert len(t.images) == 5 == len(set(t.images)) and t.cam_xy.shape == (5, 2)
        np.testing.assert_allclose(t.obj_xy, [0.1, -0.2], atol=1e-9)
        assert t.as_dict()["images"] == list(t.images)
    assert len({t.images for t in tracks}) == 4
    # An explicit list of images is exactly one track, in the scan that has all of them.
    names = tuple(det[det["scan"] == "s2"]["image"].iloc[:3])
    (one,) = P.plan_tracks(det, "t", 4, 3, 0, intr, steps, explicit=names)
    assert one.scan == "s2" and one.images == names
    with pytest.raises(TrackError, match="not every image"):
        P.plan_tracks(det, "t", 4, 3, 0, intr, steps, explicit=("nope.jpg",))
    with pytest.raises(TrackError, match="no AVD view"):
        P.plan_tracks(det.iloc[:0], "t", 4, 3, 0, intr, steps)


def test_scores_are_gathered_per_view_in_pass_order():
    df, scores = scene(scans=("s1",), n_s=3, D=4)
    df = df.sample(frac=1.0, random_state=1)   # row order must not matter (the index keys the scores)
    det = P.target_views(df, "t", 4)
    (info,) = P.plan_tracks(det, "t", 1, 4, 0, {"s1": (FX, CX)}, {"s1": 0.3})
    samples = P.track_samples(df, scores, info, max_difficulty=4)
    drop, own = samples[:, :, [3, 1]], samples[:, :, [0, 2, 2]]
    assert drop.shape == (4, 3, 2) and own.shape == (4, 3, 3)
    first = df[(df["image"] == info.images[0]) & (df["pass"] >= 0)].sort_values("pass")
    np.testing.assert_array_equal(drop[0], scores[first.index][:, [3, 1]])
    np.testing.assert_array_equal(own[0][:, 1], own[0][:, 2])
    missing = df[~((df["image"] == info.images[2]) & (df["pass"] >= 0))]
    with pytest.raises(TrackError, match="no MC-dropout samples"):
        P.track_samples(missing, scores, info, 4)


def test_scores_of_a_view_with_two_boxes_of_the_target_keep_the_row_filter_order():
    # Two boxes of the target in one image repeat its passes: the rows then come in the order the
    # filter-and-sort of each view gave them (pandas' sort of the passes), not interleaved otherwise.
    df, scores = scene(scans=("s1",), n_s=12, D=4)
    det = P.target_views(df, "t", 4)
    (info,) = P.plan_tracks(det, "t", 1, 4, 0, {"s1": (FX, CX)}, {"s1": 0.3})
    second = df[(df["image"] == info.images[1]) & (df["pass"] >= 0)]
    df2 = pd.concat([df, second.assign(box_x0=second["box_x0"] + 5)], ignore_index=True)
    scores2 = np.concatenate([scores, scores[second.index] + 0.5])
    df2 = df2.sample(frac=1.0, random_state=3)
    rows = df2[(df2["instance"] == "t") & (df2["scan"] == "s1") & (df2["pass"] >= 0) & (df2["difficulty"] <= 4)]
    want = [scores2[rows[rows["image"] == n].sort_values("pass").index.to_numpy()] for n in info.images]
    assert len(want[1]) == 24 and len(want[0]) == 12
    with pytest.raises(TrackError, match="different numbers of dropout samples"):
        P.track_samples(df2, scores2, info, 4)
    doubled = dataclasses.replace(info, images=(info.images[1],))
    np.testing.assert_array_equal(P.track_samples(df2, scores2, doubled, 4)[0], want[1])


def _cell(variant="default", track=0, settings=None):
    models = ring_models()
    data = make_track(models, truth=1, K=4)
    s = settings or (P.Setting("biased", "b", 0.2, (0.1, 0.0), 1, 3),
                     P.Setting("randomized", "r", 0.2, (0.0, 0.0), 4, 3))
    return models, P.Cell(variant, "t", track, "s1", tuple(models.classes), tuple(models.components), 1, data,
                          s, seed=7, var_floor=1e-6, difficulty=variant == "default")


def test_each_cell_draws_its_own_noise_whatever_the_grid_order_or_variant():
    models, a = _cell()
    _, b = _cell(variant="ablation")
    banks = {"default": models, "ablation": models}
    ra, rb = P.run_cell(banks, a), P.run_cell(banks, b)
    assert set(ra["posts"]) == {("biased", "b"), ("randomized", "r")}
    assert ra["posts"][("randomized", "r")][E.MODEL_BASED].shape == (4, 4, 3)
    for key in ra["posts"]:   # an ablation with the same models sees the same noise
        for m in ra["posts"][key]:
            np.testing.assert_array_equal(ra["posts"][key][m], rb["posts"][key][m])
    assert ra["difficulty"] is not None and rb["difficulty"] is None
    np.testing.assert_array_equal(P.run_cell(banks, a)["posts"][("randomized", "r")][E.MODEL_BASED],
                                  ra["posts"][("randomized", "r")][E.MODEL_BASED])
    _, other = _cell(track=1)
    assert not np.array_equal(P.run_cell(banks, other)["posts"][("randomized", "r")][E.MODEL_BASED],
                              ra["posts"][("randomized", "r")][E.MODEL_BASED])
    s = a.settings[1]
    assert P.cell_rng(7, "t", 0, s).random() == P.cell_rng(7, "t", 0, s).random()
    assert P.cell_rng(7, "t", 0, s).random() != P.cell_rng(7, "t", 0, a.settings[0]).random()


def test_yaw_comes_from_the_truth_sidecar_or_the_config():
    per_scan = {"scans": {"s1": {"instances": {"t": {"yaw_deg": 30.0, "position": [0, 0]}}}},
                "instances": {"t": {"yaw_deg": 10.0, "position": [0, 0]}, "u": {"yaw_deg": -45.0}}}
    assert P.yaw_for("t", "s1", per_scan, "truth", 0.0, "all", ()) == pytest.approx(math.radians(30.0))
    assert P.yaw_for("u", "s1", per_scan, "truth", 0.0, "all", ()) == pytest.approx(math.radians(-45.0))
    assert P.truth_entry(per_scan, "s9", "t")["yaw_deg"] == 10.0        # a layout shared by every scan
    assert P.truth_entry(None, "s1", "t") is None
    with pytest.raises(ValueError, match="truth.json has no yaw for 'v'"):
        P.yaw_for("v", "s1", per_scan, "truth", 0.0, "all", ())
    assert P.yaw_for("u", "s1", None, "config", 0.0, ("t", "u"), (5.0, 60.0)) == pytest.approx(math.radians(60.0))
    assert P.yaw_for("t", "s1", None, "config", 12.0, ("t",), ()) == pytest.approx(math.radians(12.0))
