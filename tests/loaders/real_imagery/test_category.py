"""Category folds (pure parts): class and view names, the pairing that places every held-out
instance, fold-restricted candidate sets, and the cut-out over black or clutter."""
from __future__ import annotations

import numpy as np
import pytest

from loaders.real_imagery.category import assign_targets, fold_class, nearest_azimuth, view_code
from loaders.real_imagery.clutter import LABEL_ROWS, clutter_patch, cutout_patch, patch_shape
from pipeline.evaluation.grid.candidates import candidate_sets, fold_of


def test_names():
    assert fold_class("cow", 7) == "cow__f7" and fold_of("cow__f7") == "7"
    assert view_code(3, 22.5) == 3 * 360 + 22 and view_code(3, 67.5) == 3 * 360 + 68   # the names' rounding
    with pytest.raises(ValueError, match="fold suffix"):
        fold_of("coil_obj002")
    assert nearest_azimuth(11.0, [0.0, 22.5]) == 0.0 and nearest_azimuth(345.0, [0.0, 337.5]) == 337.5 and nearest_azimuth(352.0, [0.0, 337.5]) == 0.0


def test_pairing_places_each_target_before_any_twice():
    targets = [fold_class(c, f) for c in ("a", "b", "c") for f in (1, 2, 3)]   # 9
    located = {"s1": [f"i{k}" for k in range(5)], "s2": [f"j{k}" for k in range(7)], "s3": [f"k{k}" for k in range(2)]}
    out = assign_targets(located, targets, seed=0)
    assert out == assign_targets(located, targets, seed=0)
    placed = [t for scan in out.values() for t in scan.values()]
    assert len(placed) == 14 and set(placed) == set(targets)          # every target placed
    counts = {t: placed.count(t) for t in targets}
    assert max(counts.values()) - min(counts.values()) <= 1          # spread evenly
    for scan in out.values():
        assert len(set(scan.values())) == len(scan)                  # distinct within a scan
    other = assign_targets(located, targets, seed=1)
    assert other != out


def test_fold_candidates_never_leave_the_fold():
    pool = [fold_class(c, f) for c in "abcdefgh" for f in (1, 2, 3)]
    for mode in ("sampled", "all"):
        sets = candidate_sets(pool, pool, 4, mode, 0, folds=True)
        for t, cands in sets.items():
            assert t in cands and {fold_of(c) for c in cands} == {fold_of(t)}
            assert len(cands) == (4 if mode == "sampled" else 8)
    mixed = candidate_sets(pool, pool, 4, "sampled", 0)        # without folds the draw mixes them
    assert any(len({fold_of(c) for c in cands}) > 1 for cands in mixed.values())
    means = {c: np.random.default_rng(len(c) + ord(c[0])).random(5) for c in pool}
    hard = candidate_sets(pool, pool, 3, "hard", 0, class_means=means, folds=True)
    assert all({fold_of(c) for c in cands} == {fold_of(t)} for t, cands in hard.items())


def _photo():
    rgb = np.zeros((64, 64, 3), np.uint8)
    rgb[:] = (40, 60, 160)            # blue cloth
    rgb[20:44, 16:48] = (200, 180, 20)
    alpha = np.zeros((64, 64), np.float32)
    alpha[20:44, 16:48] = 1.0
    return rgb, alpha > 0.5, alpha


def test_cutout_over_black_drops_the_cloth():
    rgb, mask, alpha = _photo()
    patch, (dx, dy) = cutout_patch(rgb, mask, alpha, 64, 48, None)
    assert patch.shape[:2] == patch_shape(mask, 64, 48)
    inner = patch[dy + 4:dy + 44, dx + 4:dx + 60]
    assert np.abs(inner.astype(int) - [200, 180, 20]).max() <= 2     # the object
    assert patch[:dy - 1].max() == 0 and patch[:, :dx - 1].max() == 0  # no blue cloth: black


def test_cutout_over_clutter_uses_the_frame_below_its_label():
    rgb, mask, alpha = _photo()
    frame = np.zeros((270, 480, 3), np.uint8)
    frame[:LABEL_ROWS] = 255                                         # the label band: never used
    frame[LABEL_ROWS:] = (10, 120, 90)
    shape = patch_shape(mask, 80, 60)
    bg = clutter_patch([frame], shape, np.random.default_rng(0))
    assert bg.shape == (*shape, 3) and (bg == [10, 120, 90]).all()
    patch, (dx, dy) = cutout_patch(rgb, mask, alpha, 80, 60, bg)
    assert (patch[:dy - 1] == [10, 120, 90]).all()                    # clutter, not black, not cloth
    assert np.abs(patch[dy + 10, dx + 10].astype(int) - [200, 180, 20]).max() <= 2


def test_classes_assembled_from_member_objects_only(tmp_path):
    import pyarrow as pa

    from loaders.real_imagery.category import class_members
    from pipeline.banks.model_bank import FeaturesError, assemble_classes
    from pipeline.infra.config import load_config
    from tests.conftest import ROOT

    cfg = load_config(ROOT / "configs" / "real_category.toml",
                      {"run": {"artifacts": str(tmp_path)},
                       "data": {"real_imagery": {"categories": ["cup", "dog", "cow", "pear"], "instances": [1, 2, 3]}}})
    members = class_members(cfg)
    assert members["cup__f2"] == ["eth80_cup1", "eth80_cup3"] and len(members) == 12
    members = {k: v for k, v in members.items() if k[:3] in ("cup", "dog")}
    objs = [f"eth80_{c}{i}" for c in ("cup", "dog") for i in (1, 2, 3) for _ in range(2)]
    table = pa.table({"object": objs, "angle_deg": [360 * int(o[-1]) + k for o in objs[::2] for k in (0, 22)]})
    out = assemble_classes(table, members, tmp_path)
    got = out.to_pandas()
    for cls, d in got.groupby("object"):
        fold = int(cls[-1])
        assert set(d["angle_deg"] // 360) == {1, 2, 3} - {fold} and len(d) == 4
    with pytest.raises(FeaturesError, match="eth80_cup9"):
        assemble_classes(table, {"cup__f1": ["eth80_cup9"]}, tmp_path)
