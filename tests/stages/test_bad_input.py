"""Bad input, on generated fixtures: one skip policy counted in the manifest of the stage that
meets the bad entry, corrupt JPEGs and npz files named, calibration and AVD format errors named."""
from __future__ import annotations

from pipeline.method.gp_files import load_bank, save_bank
import json
import os
from pathlib import Path

import numpy as np
import pytest

from loaders.errors import BadInputError, SkipLog, SkipPolicy
from tests.support.readers_fixtures import make_avd_scan, make_bigbird_object, write_jpeg

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

ROOT = Path(__file__).resolve().parents[2]


def corrupt_entropy(data: bytes) -> bytes:
    """A JPEG whose markers are intact (SOI, SOS, EOI) but whose entropy-coded data stops early."""
    sos = data.find(b"\xff\xda")
    start = sos + 2 + int.from_bytes(data[sos + 2:sos + 4], "big")
    eoi = data.rfind(b"\xff\xd9")
    return data[:start + (eoi - start) // 3] + b"\xff\xd9"


def real_cfg(tmp_config, tmp_path, skip=True, **over):
    bb, avd = tmp_path / "bigbird", tmp_path / "avd"
    return tmp_config({"data": {"source": "real", "bigbird_root": str(bb), "avd_root": str(avd),
                                "scans": ["Home_001_1"], "skip_bad_views": skip, **over},
                       "features": {"bigbird_cameras": [1]}})


@pytest.fixture
def real_data(tmp_path):
    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    return make_avd_scan(tmp_path / "avd")


def _bad_box_and_missing_image(ann):
    first = sorted(ann)[0]
    ann[first]["bounding_boxes"].append([50, 50, 40, 60, 2, 1])          # degenerate box
    ann["Home_001_1_nope.jpg"] = {"bounding_boxes": []}                   # names a missing image


def test_skips_on_counted_in_the_data_manifest_and_off_stops_the_data_stage(tmp_config, tmp_path):
    from stages.framework.runner import ensure, read_manifest

    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    sk = read_manifest(cfg, "data")["extra"]["skipped"]["avd"]
    assert sk["skipped"] == 2
    assert any("degenerate box" in e for e in sk["examples"])
    assert any("Home_001_1_nope.jpg" in e and "annotations.json" in e for e in sk["examples"])

    off = real_cfg(tmp_config, tmp_path, skip=False, seed=1)   # another key: reruns
    with pytest.raises(BadInputError, match=r"annotations\.json: .*(nope|degenerate)"):
        ensure(off, "data")


def test_policy_gives_the_same_log_to_every_reader_and_raises_when_off(tmp_path):
    from loaders.avd import AVDScan

    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    on = SkipPolicy(True)
    scan = AVDScan(tmp_path / "avd", "Home_001_1", skip=on.log("avd", "AVD entry"))
    assert on.count == 2 and set(on.summary()) == {"avd"}
    assert len(scan.images) == 24                            # the images themselves are kept
    off = SkipPolicy(False)
    assert off.log("avd") is None and off.summary() == {}
    with pytest.raises(BadInputError):
        off.handle(BadInputError("x.jpg", "bad"), "avd")
    with pytest.raises(BadInputError, match="annotations.json"):
        AVDScan(tmp_path / "avd", "Home_001_1", skip=off.log("avd"))


def test_entropy_cut_jpeg_is_named_not_scored(tmp_path, capfd):
    from loaders.bigbird import BigBirdObject
    from loaders.jpeg import read_rgb

    p = tmp_path / "x.jpg"
    rng = np.random.default_rng(0)
    write_jpeg(p, rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    good = read_rgb(p)
    assert good.shape == (48, 64, 3)
    p.write_bytes(corrupt_entropy(p.read_bytes()))
    with pytest.raises(BadInputError, match=r"x\.jpg: corrupt JPEG: libjpeg reports .*premature end of data segment"):
        read_rgb(p)
    assert "Corrupt JPEG data" not in capfd.readouterr().err  # captured, not printed without a name

    make_bigbird_object(tmp_path / "bb", angles=(0, 3, 6), cameras=(1,))
    view = tmp_path / "bb" / "aunt_jemima_original_syrup" / "NP1_3.jpg"
    view.write_bytes(corrupt_entropy(view.read_bytes()))
    obj = BigBirdObject(tmp_path / "bb" / "aunt_jemima_original_syrup")
    skip = SkipLog("BigBIRD view")
    recs = list(obj.iter_views((1,), skip=skip))
    assert [r.view.angle for r in recs] == [0, 6]
    assert skip.count == 1 and "NP1_3.jpg" in skip.examples[0] and "premature end" in skip.examples[0]


def test_other_c_stderr_output_is_passed_on(capfd):
    from loaders.image_gate import c_stderr_captured

    with c_stderr_captured() as lines:
        os.write(2, b"unrelated native message\nCorrupt JPEG data: bad Huffman code\n")
    assert any("Huffman" in ln for ln in lines)
    err = capfd.readouterr().err
    assert "unrelated native message" in err and "Huffman" not in err


def test_bad_npz_files_are_named(tmp_path):
    from pipeline.infra.cache import NpzFileError, load_npz
    from pipeline.method.gp import ModelFileError
    from tests.pipeline.method.test_gp import make_models

    good = tmp_path / "g.npz"
    np.savez(good, a=np.arange(3))
    assert load_npz(good)["a"].tolist() == [0, 1, 2]
    trunc = tmp_path / "gp_models.npz"
    trunc.write_bytes(good.read_bytes()[:60])
    with pytest.raises(NpzFileError, match=r"gp_models\.npz: not a valid \.npz file \(truncated"):
        load_npz(trunc)
    rnd = tmp_path / "bias_maps.npz"
    rnd.write_bytes(np.random.default_rng(0).bytes(400))
    with pytest.raises(NpzFileError, match=r"bias_maps\.npz: not a valid \.npz file") as e:
        load_npz(rnd)
    assert "pickle" not in str(e.value)
    obj = tmp_path / "obj.npz"
    np.savez(obj, a=np.array([{"x": 1}], dtype=object))
    with pytest.raises(NpzFileError, match="object arrays"):
        load_npz(obj)

    models = tmp_path / "models"
    save_bank(make_models(np.random.default_rng(1)), models)
    index = json.loads((models / "index.json").read_text())
    index.pop("sha256")                            # an index without digests: the npz check still names it
    (models / "index.json").write_text(json.dumps(index))
    f = models / index["files"]["class_0"]
    f.write_bytes(np.random.default_rng(2).bytes(500))
    with pytest.raises(ModelFileError, match="not a valid .npz file") as e:
        load_bank(models)
    assert "pickle" not in str(e.value) and str(f) in str(e.value)


def test_object_without_calibration_is_a_named_skip_or_error(tmp_config, tmp_path, real_data):
    from stages.framework.runner import ensure, read_manifest

    make_bigbird_object(tmp_path / "bigbird", name="crystal_hot_sauce", angles=(0, 3), cameras=(1,))
    calib = tmp_path / "bigbird" / "crystal_hot_sauce" / "calibration.h5"
    calib.unlink()
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    sk = read_manifest(cfg, "data")["extra"]["skipped"]["bigbird"]
    assert sk["skipped"] == 1 and str(calib) in sk["examples"][0]
    with pytest.raises(BadInputError, match=f"{calib}: object folder has views but no calibration"):
        ensure(real_cfg(tmp_config, tmp_path, skip=False), "data")


def test_missing_calibration_key_is_one_error_naming_file_and_key(tmp_config, tmp_path, real_data):
    import h5py

    from stages.features import bigbird_objects

    calib = tmp_path / "bigbird" / "aunt_jemima_original_syrup" / "calibration.h5"
    with h5py.File(calib, "a") as f:
        del f["H_NP1_from_NP5"]
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    policy = SkipPolicy(True)
    with pytest.raises(BadInputError, match=f"{calib}: missing HDF5 dataset 'H_NP1_from_NP5'"):
        bigbird_objects(cfg, tmp_path / "bigbird", policy)
    assert policy.count == 0                       # not one skip per view
    from stages.framework.runner import ensure
    with pytest.raises(BadInputError, match="H_NP1_from_NP5"):
        ensure(cfg, "data")                        # and it stops the run before any scoring


@pytest.mark.parametrize("what", ["json", "instance_map", "mat"])
def test_avd_format_errors_stop_the_data_stage(tmp_config, tmp_path, real_data, what):
    from stages.framework.runner import ensure

    folder = tmp_path / "avd" / "Home_001_1"
    target = {"json": folder / "annotations.json", "instance_map": tmp_path / "avd" / "instance_id_map.txt",
              "mat": folder / "image_structs.mat"}[what]
    target.write_text({"json": "{not json", "instance_map": "background 0\nbroken line here\n",
                       "mat": "not a mat file"}[what])
    with pytest.raises(BadInputError, match=str(target)):
        ensure(real_cfg(tmp_config, tmp_path, skip=True), "data")


def test_skip_counts_are_read_back_per_stage(tmp_config, tmp_path):
    from stages.framework.runner import ensure, read_manifest

    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    assert read_manifest(cfg, "data")["extra"]["skipped"]["avd"]["skipped"] == 2


def test_many_skips_are_counted_but_not_all_logged(caplog):
    skip = SkipLog("AVD entry")
    with caplog.at_level("WARNING", logger="viewfuse.loaders"):
        for i in range(500):
            skip.skip(BadInputError(f"img{i}.jpg", "corrupt JPEG"))
    assert skip.count == 500 and skip.reasons == {"corrupt JPEG": 500} and len(skip.examples) == 20
    assert len(caplog.records) == SkipLog.LOG_FIRST + 1
    assert "counted, not logged" in caplog.records[-1].getMessage()
