"""The ETH-80 writer's sides: an instance that cannot be modelled is left out in the data stage,
named (the check the COIL writer calls too); frames beyond max_view_error_deg are refused and
counted; the training views sit on the frames' background kind unless a mismatch is asked for;
instance and category level differ in the class models' training set only (same frames)."""
from __future__ import annotations

import hashlib
import json
import shutil

import cv2
import numpy as np
import pytest

from tests.conftest import ROOT
from tests.loaders.realdata import need

CATS, INSTS = ["apple", "car", "cup"], [1, 2, 3]


def _tree(tmp_path, keep=None):
    """A copy of three categories x three instances of ../shared/realdata/eth80; ``keep`` =
    {folder: azimuth names kept} thins an instance's ring (views and maps)."""
    src = need("eth80")
    root = tmp_path / "eth80"
    for c in CATS:
        for i in INSTS:
            folder = src / f"{c}{i}"
            (root / folder.name).mkdir(parents=True)
            for p in folder.glob("*.png"):
                az = p.name.replace("-map", "").split("-")[2][:3]
                if keep and folder.name in keep and az not in keep[folder.name]:
                    continue
                shutil.copy(p, root / folder.name)
    return root


def _write(tmp_path, root, skip=True, **ri):
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.category import write_real_category
    from pipeline.infra.config import load_config

    out = tmp_path / f"out_{len(list(tmp_path.glob('out_*')))}"
    cfg = load_config(ROOT / "configs" / "real_category.toml", {
        "run": {"artifacts": str(tmp_path / "art")},
        "data": {"eth80_root": str(root), "avd_root": str(need("avd")), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1"], "skip_bad_views": skip,
                 "real_imagery": {"categories": CATS, "instances": INSTS, **ri}},
        "evaluate": {"n_candidates": 3}})
    skips = SkipPolicy(skip)
    extra, _ = write_real_category(cfg, out / "bigbird", out / "avd", out / "truth.json", skips)
    return out, extra, json.loads((out / "truth.json").read_text()), skips


def test_an_instance_with_three_views_is_left_out_named(tmp_path):
    from loaders.errors import BadInputError

    root = _tree(tmp_path, keep={"car2": {"000", "090", "180"}})
    with pytest.raises(BadInputError, match=r"car2: eth80_car2: 3 readable training views at data.real_imagery"
                                            r".view_split = 'none', elevations = \[90\], fewer than models.min_views = "
                                            r"8; instance left out"):
        _write(tmp_path, root, skip=False)
    out, extra, truth, skips = _write(tmp_path, root)
    assert truth["left_out_instances"] == ["eth80_car2"] == extra["left_out_instances"]
    assert "eth80_car2" in json.dumps(skips.summary()) and skips.count >= 1       # counted, named
    assert "car__f2" not in truth["classes"] and "car__f2" not in truth["targets"]
    assert truth["classes"]["car__f1"] == ["eth80_car3"] and truth["classes"]["apple__f2"] == ["eth80_apple1", "eth80_apple3"]
    assert not (out / "bigbird" / "eth80_car2").exists()
    assert "car__f2" not in (out / "avd" / "instance_id_map.txt").read_text()
    # the models stage reads the classes the data stage made, not the config's
    from loaders.real_imagery.category import class_members
    from pipeline.infra.config import load_config
    cfg = load_config(ROOT / "configs" / "real_category.toml", {"run": {"artifacts": str(tmp_path / "a2")},
                      "data": {"real_imagery": {"categories": CATS, "instances": INSTS}},
                      "evaluate": {"n_candidates": 3}})
    assert class_members(cfg, truth) == truth["classes"] and "car__f2" in class_members(cfg)


def test_sparse_azimuths_frames_beyond_the_bound_are_refused_and_counted(tmp_path):
    # cup3 keeps 8 views, all on one half of the ring: modellable, but most bearings are far from any
    half = {"000", "022", "045", "068", "090", "112", "135", "158"}
    root = _tree(tmp_path, keep={"cup3": half})
    _, extra, truth, _ = _write(tmp_path, root)
    inst = truth["scans"]["Home_005_1"]["instances"]
    ve = truth["view_error_deg"]
    assert extra["view_error_deg"] == ve and ve["bound"] == 11.25
    assert ve["refused"] == sum(r["frames_refused_view_error"] for r in inst.values()) > 0
    assert ve["frames"] == ve["refused"] + sum(r["frames"] for r in inst.values())
    sparse = inst["cup__f3"]
    assert sparse["frames_refused_view_error"] > 0 and sparse["max_view_offset_deg"] > 11.25
    assert set(sparse["azimuths_used"]) <= {float(a) for a in (0, 22.5, 45, 67.5, 90, 112.5, 135, 157.5)}
    for name, rec in inst.items():
        if name != "cup__f3":
            assert rec["frames_refused_view_error"] == 0 and rec["max_view_offset_deg"] <= 11.25 + 1e-9
    # no bound wide enough: the same instance's frames all come back
    _, _, wide, _ = _write(tmp_path, root, max_view_error_deg=180.0)
    assert wide["view_error_deg"]["refused"] == 0
    assert wide["scans"]["Home_005_1"]["instances"]["cup__f3"]["frames"] == sparse["frames"] + sparse["frames_refused_view_error"]


def _outside(folder, code):
    """Mean RGB of a training view outside its (dilated) mask: its background."""
    rgb = cv2.imread(str(folder / f"NP1_{code}.jpg"))[:, :, ::-1].astype(float)
    pbm = (folder / "masks" / f"NP1_{code}_mask.pbm")
    from loaders.pbm import read_pbm
    mask = cv2.dilate(read_pbm(pbm).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    return rgb[~mask].mean(axis=0), rgb[~mask].std(axis=0)


@pytest.mark.slow   # four writes
@pytest.mark.parametrize("background,train_background,expect", [
    ("black", "same", "black"), ("black", "original", "cloth"), ("avd_frames", "same", "clutter"),
    ("avd_frames", "black", "black")])
def test_training_background_follows_the_frames_unless_told(tmp_path, background, train_background, expect):
    root = _tree(tmp_path)
    out, extra, truth, _ = _write(tmp_path, root, background=background, train_background=train_background)
    side = background if train_background == "same" else train_background
    assert truth["background"] == {"frames": background, "training": side, "train_pad": "surround"} == extra["background"]
    folder = out / "bigbird" / "eth80_apple1"
    means = [_outside(folder, 360 + a) for a in (0, 90, 180)]
    for mean, std in means:
        if expect == "black":
            assert mean.max() < 8
        elif expect == "cloth":
            assert mean[2] > mean[0] + 30          # ETH-80's blue cloth
        else:
            assert mean.max() > 25 and std.max() > 10   # a real room: neither black nor a flat cloth
    if expect == "clutter":
        assert len({round(float(m[0].sum()), 1) for m in means}) == 3    # a seeded region per view


@pytest.mark.slow   # two writes
def test_instance_and_category_level_share_every_frame(tmp_path):
    root = _tree(tmp_path)
    cat_out, _, cat, _ = _write(tmp_path, root, view_split="alternate", max_view_error_deg=22.5)
    ins_out, _, ins, _ = _write(tmp_path, root, view_split="alternate", max_view_error_deg=22.5,
                                class_level="instance")

    def digest(avd):
        return {p.relative_to(avd).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(avd.rglob("*")) if p.is_file()}
    assert digest(cat_out / "avd") == digest(ins_out / "avd")            # the same frames and annotations
    assert cat["scans"] == ins["scans"] and cat["targets"] == ins["targets"]
    assert cat["classes"]["car__f2"] == ["eth80_car1", "eth80_car3"] and ins["classes"]["car__f2"] == ["eth80_car2"]
    assert ins["class_level"] == "instance" and cat["class_level"] == "category"
    for t, rec in ins["targets"].items():
        assert all(a % 45 == 0 for a in rec["training_azimuths"]) and all(a % 45 == 22.5 for a in rec["frame_azimuths"])
    for rec in ins["scans"]["Home_005_1"]["instances"].values():
        assert all(a % 45 == 22.5 for a in rec["azimuths_used"])          # never a photograph a class was fitted on
    codes = sorted(int(p.stem.split("_")[1]) % 360 for p in (ins_out / "bigbird" / "eth80_car2").glob("NP1_*.jpg"))
    assert codes == [0, 45, 90, 135, 180, 225, 270, 315]
