"""The 15 real AVD scans' metadata (../shared/realdata/avd: annotations.json, image_structs.mat,
present_instance_names.txt; no frames) through the reader, the grid points and the locator.

The counts are the real files' (measured once, fixed with the data): a change in the reader that
refuses a legitimate entry, or lets a defect through, changes them."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tests.loaders.realdata import need

# scan: (images, boxes kept, boxes refused, difficulty-0 boxes given the size rule's level,
#        boxes clipped to the image edge, grid points)
COUNTS = {
    "Home_001_1": (1536, 4735, 0, 138, 0, 128), "Home_001_2": (1392, 5493, 0, 2, 0, 116),
    "Home_002_1": (1224, 2202, 0, 0, 0, 102), "Home_003_1": (1500, 4827, 2, 16, 0, 125),
    "Home_003_2": (1548, 5336, 0, 1, 0, 129), "Home_004_1": (1488, 2118, 0, 25, 0, 124),
    "Home_004_2": (1512, 2502, 0, 44, 0, 126), "Home_005_1": (744, 1861, 0, 0, 0, 62),
    "Home_006_1": (2412, 6227, 0, 0, 0, 201), "Home_007_1": (1728, 2757, 0, 0, 1, 144),
    "Home_008_1": (840, 2331, 0, 0, 0, 70), "Home_010_1": (1320, 2139, 0, 29, 2, 110),
    "Home_013_1": (1644, 3376, 0, 26, 0, 137), "Home_014_1": (696, 1190, 0, 0, 0, 58),
    "Home_015_1": (972, 2740, 0, 0, 0, 81),
}
# Home_006_1 holds two copies of each of these, about 9 m apart: their rays meet nowhere.
DUPLICATED = {"aunt_jemima_original_syrup", "mahatma_rice", "nature_valley_granola_thins_dark_chocolate",
              "nature_valley_sweet_and_salty_nut_roasted_mix_nut", "red_bull", "softsoap_white"}


@pytest.fixture(scope="module")
def real():
    """{scan: (ScanPaths with no residual limit, the same with the default limit, AVDScan read with
    skips off or the BadInputError it raised, raw annotations.json)}."""
    from loaders.avd import AVDScan
    from loaders.avd_paths import scan_paths
    from loaders.errors import BadInputError, SkipLog

    root = need("avd")
    out = {}
    for scan in COUNTS:
        try:
            strict = AVDScan(root, scan, frames=False)
        except BadInputError as e:
            strict = e
        every = scan_paths(root, scan, max_residual_m=math.inf, skip=SkipLog("avd"))
        default = scan_paths(root, scan, skip=SkipLog("avd"))
        raw = json.loads((root / scan / "annotations.json").read_text())
        out[scan] = (every, default, strict, raw)
    return out


def test_real_scans_are_the_fifteen(real):
    root = need("avd")
    assert sorted(p.name for p in root.iterdir() if p.is_dir()) == sorted(COUNTS)


@pytest.mark.parametrize("scan", sorted(COUNTS))
def test_every_real_scan_parses(real, scan):
    from loaders.avd import AVDScan

    every, _, strict, raw = real[scan]
    n_img, n_box, n_refused, n_assigned, n_clipped, n_grid = COUNTS[scan]
    assert len(every.nodes) == len(raw) == n_img           # every annotated image read
    assert every.skips.count == n_refused and every.n_boxes == n_box
    assert (every.box_notes.unassigned, every.box_notes.clipped) == (n_assigned, n_clipped)
    assert sum(len(v["bounding_boxes"]) for v in raw.values()) == n_box + n_refused
    if n_refused:   # the only refusals: zero-area boxes, a defect of the file
        assert set(every.skips.reasons) and all("degenerate box" in r for r in every.skips.reasons)
        assert isinstance(strict, Exception) and "degenerate box" in str(strict)
    else:           # the skip policy off reads the scan as well
        assert isinstance(strict, AVDScan) and sum(len(i.boxes) for i in strict.images.values()) == n_box
        assert (strict.box_notes.unassigned, strict.box_notes.clipped) == (n_assigned, n_clipped)
        assert all(1 <= b.difficulty <= 5 for i in strict.images.values() for b in i.boxes)
        assert all(0 <= b.x0 < b.x1 <= 1920 and 0 <= b.y0 < b.y1 <= 1080 for i in strict.images.values()
                   for b in i.boxes)
    # grid points: the move graph's rotate rings, 12 headings each
    grid = [n.grid_point for n in every.nodes.values()]
    assert len(set(grid)) == n_grid and set(np.bincount(grid)) == {12}


@pytest.mark.parametrize("scan", ["Home_001_1", "Home_002_1"])
def test_real_grid_step_is_the_capture_grid(real, scan):
    """Rounded positions read the ~2 cm spread of one stop as the grid step; grid points give ~29 cm."""
    from pipeline.scene.rays import grid_step

    every = real[scan][0]
    xy = np.array([n.position for n in every.nodes.values()])
    assert grid_step(xy) < 0.02
    assert 0.27 < every.grid_step_m < 0.31


def test_real_tracks_visit_distinct_grid_points(real):
    from pipeline.evaluation.grid.track import select_tracks
    from pipeline.scene.rays import facing_error, grid_step

    every = real["Home_001_1"][1]
    repeats_old = repeats_new = n = 0
    for loc in every.instances.values():
        ims = sorted(loc.boxes)
        if len(ims) < 30:
            continue
        cam = np.array([every.nodes[i].position for i in ims])
        gid = np.array([every.nodes[i].grid_point for i in ims])
        err = facing_error(cam, np.array([every.nodes[i].heading for i in ims]), loc.xy)
        new = select_tracks(cam, loc.xy, err, 9, 4, seed=0, grid_step=every.grid_step_m, grid_id=gid)
        old = select_tracks(cam, loc.xy, err, 9, 4, seed=0, grid_step=grid_step(cam))
        repeats_new += sum(9 - len(set(gid[t.index])) for t in new)
        repeats_old += sum(9 - len(set(gid[t.index])) for t in old)
        n += len(new)
    assert n >= 20 and repeats_new == 0
    assert repeats_old > 0   # what the position cells did on real poses


def test_real_rays_meet_and_the_duplicates_are_flagged(real):
    every = [loc.residual_m for ev, *_ in real.values() for loc in ev.instances.values()]
    kept = [loc.residual_m for _, d, *_ in real.values() for loc in d.instances.values()]
    assert len(every) == 286 and len(kept) == 280
    assert np.median(kept) < 0.05 and max(kept) < 0.25
    flagged = {(e["scan"], e["instance"]): e for _, d, *_ in real.values() for e in d.excluded}
    assert set(flagged) == {("Home_006_1", i) for i in DUPLICATED}
    for e in flagged.values():
        assert e["residual_m"] > 2.0 and "do not meet at one point" in e["reason"]
        assert e["instance"] not in real["Home_006_1"][1].instances
    # every instance located within a scan it was annotated in is located (or flagged) in it
    for ev, d, *_ in real.values():
        assert set(ev.instances) == set(d.instances) | {e["instance"] for e in d.excluded}
