"""The track planner asks every scan before it gives up on a target: tracks the first scan cannot
give are asked of the next, whatever ``evaluate.tracks_per_target`` is."""
import numpy as np
import pytest

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.track import TrackError
from tests.pipeline.evaluation.grid.test_population import CX, FX, scene

INTR = {s: (FX, CX) for s in ("s1", "s2", "s3")}
STEPS = {s: 0.3 for s in ("s1", "s2", "s3")}


def _det(scans=("s1", "s2"), few_in=("s1",), keep=3):
    df, _ = scene(scans=scans)
    det = P.target_views(df, "t", 4)
    for s in few_in:  # this scan sees the target from only ``keep`` viewpoints
        imgs = sorted(det.loc[det["scan"] == s, "image"].unique())[:keep]
        det = det[(det["scan"] != s) | det["image"].isin(imgs)]
    return det.reset_index(drop=True)


@pytest.mark.parametrize("n_tracks", [1, 2, 3])
def test_a_scan_with_too_few_viewpoints_hands_its_tracks_on(n_tracks):
    tracks = P.plan_tracks(_det(), "t", n_tracks, 5, 0, INTR, STEPS)
    assert len(tracks) == n_tracks and {t.scan for t in tracks} == {"s2"}
    assert [t.track for t in tracks] == list(range(n_tracks))


def test_three_scans_the_first_two_failing():
    det = _det(("s1", "s2", "s3"), few_in=("s1", "s2"))
    (one,) = P.plan_tracks(det, "t", 1, 5, 0, INTR, STEPS)
    assert one.scan == "s3"


def test_a_healthy_first_scan_keeps_the_old_split():
    det = _det(few_in=())
    assert [t.scan for t in P.plan_tracks(det, "t", 1, 5, 0, INTR, STEPS)] == ["s1"]
    assert sorted(t.scan for t in P.plan_tracks(det, "t", 4, 5, 0, INTR, STEPS)) == ["s1", "s1", "s2", "s2"]


def test_every_scan_failing_names_each():
    det = _det(few_in=("s1", "s2"))
    with pytest.raises(TrackError, match=r"s1: only 3 distinct viewpoints.*s2: only 3 distinct viewpoints"):
        P.plan_tracks(det, "t", 1, 5, 0, INTR, STEPS)


def test_a_skipped_target_is_named_in_the_limitations(tmp_path):
    from types import SimpleNamespace

    from pipeline.infra.datasets import described
    from reports.main.reviewer import limitations

    pop = {"skipped_targets": [{"target": "coil_obj006", "reason": "no usable track of 'coil_obj006': s1: 2 view(s)"},
                               {"target": "coil_obj007", "scan": "s2", "reason": "s2: rays", "residual_m": 0.4}],
           "tracks": [], "per_target": {}}
    ctx = SimpleNamespace(population=pop, config={"evaluate": {}}, run=SimpleNamespace(card={}, run_dir=str(tmp_path)),
                          data_source="real_imagery", source=described("real_imagery"))
    items = limitations(ctx)
    hit = [i for i in items if "skipped for want of a usable track" in i]
    assert len(hit) == 1 and hit[0].startswith("1 target was skipped") and "coil_obj006" in hit[0]
    assert "coil_obj007" not in hit[0]  # a refused scan of a target with tracks elsewhere is not a lost target
