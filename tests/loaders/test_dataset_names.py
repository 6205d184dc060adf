"""Names from dataset files (image keys, instance names, scan folders) are plain file names, and
every file a stage writes lands inside its temporary folder: each traversal form is planted and
refused, with nothing written outside."""
from __future__ import annotations

import json
import os
import shutil

import pytest

from tests.loaders.realdata import need

TRAVERSALS = ["../PWNED.jpg", "../../../../../../../../../tmp/PWNED.jpg", "/tmp/PWNED.jpg",
              "a/../../PWNED.jpg", "..\\..\\PWNED.jpg", "x\0.jpg", "..", ".", ""]


@pytest.mark.parametrize("name", TRAVERSALS)
def test_plain_name_refuses_each_traversal_form(name):
    from loaders.errors import BadInputError
    from loaders.files import plain_name

    with pytest.raises(BadInputError, match="refused") as e:
        plain_name(name, "/data/annotations.json", "image key")
    assert e.value.path == "/data/annotations.json"


@pytest.mark.parametrize("name", ["000110000010101.jpg", "coil_obj002", "Home_001_1", "a..b.jpg", "..hidden"])
def test_plain_name_keeps_ordinary_names(name):
    from loaders.files import plain_name

    assert plain_name(name, "f") == name


def _escape_targets(stage, outside):
    """(label, target) for each way a write could leave ``stage``."""
    return [("parent", stage / ".." / "PWNED"),
            ("absolute", outside / "PWNED"),
            ("nested", stage / "a" / ".." / ".." / "PWNED"),
            ("deep", stage / "avd" / "scan" / "jpg_rgb" / ".." / ".." / ".." / ".." / "PWNED"),
            ("symlinked dir", stage / "link" / "PWNED")]


@pytest.mark.parametrize("writer", ["bytes", "json", "link", "copy", "dir"])
def test_confined_writes_refuse_targets_outside_the_stage_folder(tmp_path, writer):
    from pipeline.infra.cache import (OutsideFolderError, confined_dir, confined_writes, copy_file, link_file,
                                      write_bytes, write_json)

    stage, outside = tmp_path / "run" / ".data.tmp", tmp_path / "outside"
    stage.mkdir(parents=True)
    outside.mkdir()
    (stage / "link").symlink_to(outside, target_is_directory=True)
    src = stage / "src.bin"
    src.write_bytes(b"x")
    do = {"bytes": lambda p: write_bytes(p, b"x"), "json": lambda p: write_json(p, {"a": 1}),
          "link": lambda p: link_file(src, p), "copy": lambda p: copy_file(src, p),
          "dir": lambda p: confined_dir(p)}[writer]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with confined_writes(stage):
        for label, target in _escape_targets(stage, outside):
            with pytest.raises(OutsideFolderError, match="outside the stage's temporary folder"):
                do(target)
        do(stage / "inside" / "ok.bin")  # inside stays allowed
    assert (stage / "inside" / "ok.bin").exists()
    assert not list(outside.iterdir()) and not (tmp_path / "run" / "PWNED").exists()
    after = sorted(p.name for p in tmp_path.rglob("*") if "inside" not in p.parts)
    assert after == sorted(before)


def test_unconfined_outside_a_stage(tmp_path):
    """Outside a running stage (tests, tools) the helpers write where they are told."""
    from pipeline.infra.cache import write_bytes

    write_bytes(tmp_path / "a" / ".." / "b.bin", b"x")
    assert (tmp_path / "b.bin").read_bytes() == b"x"


def test_instance_map_refuses_a_path_as_instance_name(tmp_path):
    from loaders.avd import read_instance_map
    from loaders.errors import BadInputError

    p = tmp_path / "instance_id_map.txt"
    p.write_text("good 1\n../../evil 2\n")
    with pytest.raises(BadInputError, match=r"line 2: instance name '../../evil' contains '/'"):
        read_instance_map(p)


def test_config_refuses_a_scan_that_is_a_path():
    from pipeline.infra.config import ConfigError, load_config
    from tests.conftest import ROOT

    for scan in ["../Home_001_1", "/etc", "a/../../b", ".."]:
        with pytest.raises(ConfigError, match="'data.scans' names"):
            load_config(ROOT / "configs" / "synthetic.toml", {"data": {"scans": [scan]}})


@pytest.fixture(scope="module")
def planted(tmp_path_factory):
    """A copy of one real AVD scan's metadata whose annotations.json gains an entry per traversal
    form (each a copy of a real entry), written by the real-imagery writer as the data stage would."""
    from loaders.errors import SkipPolicy
    from loaders.real_imagery.write import write_real_imagery
    from pipeline.infra.cache import confined_writes
    from pipeline.infra.config import load_config
    from tests.conftest import ROOT

    real = need("avd")
    coil = need("coil100")
    base = tmp_path_factory.mktemp("planted")
    avd = base / "avd"
    avd.mkdir()
    shutil.copy(real / "instance_id_map.txt", avd)
    shutil.copytree(real / "Home_005_1", avd / "Home_005_1")
    ann_path = avd / "Home_005_1" / "annotations.json"
    ann = json.loads(ann_path.read_text())
    entry = next(iter(ann.values()))
    victims = base / "victim"
    victims.mkdir()
    planted_keys = ["../" * 9 + str(victims / "PWNED.jpg").lstrip("/"), str(victims / "ABS.jpg"),
                    "a/../../../../NESTED.jpg", "..\\..\\BACKSLASH.jpg", "link/ESCAPE.jpg"]
    for k in planted_keys:
        ann[k] = dict(entry, bounding_boxes=[])
    ann_path.write_text(json.dumps(ann))
    stage = base / "run" / ".data.tmp"
    stage.mkdir(parents=True)
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(base / "artifacts")},
        "data": {"coil_root": str(coil), "avd_root": str(avd), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1"],
                 "real_imagery": {"objects": [2, 3]}}, "evaluate": {"n_candidates": 2}})
    skips = SkipPolicy(True)
    with confined_writes(stage):
        write_real_imagery(cfg, stage / "bigbird", stage / "avd", stage / "truth.json", skips)
    return base, stage, victims, planted_keys, skips, entry


@pytest.mark.slow
def test_real_imagery_writer_writes_nothing_outside_for_planted_keys(planted):
    base, stage, victims, keys, skips, _ = planted
    assert not list(victims.iterdir())
    assert sorted(p.name for p in base.iterdir()) == ["avd", "run", "victim"]
    assert sorted(p.name for p in (base / "run").iterdir()) == [".data.tmp"]
    outside = [p for p in base.rglob("*") if p.is_file() and stage not in p.parents and (base / "avd") not in p.parents]
    assert outside == []
    written = json.loads((stage / "avd" / "Home_005_1" / "annotations.json").read_text())
    assert not set(keys) & set(written)
    reasons = skips.summary()["avd"]["reasons"]
    assert sum(n for r, n in reasons.items() if "image key" in r and "refused" in r) == len(keys)


@pytest.mark.slow
def test_real_imagery_writer_stops_on_a_planted_key_with_skips_off(planted, tmp_path):
    """With data.skip_bad_views off the first planted key stops the reader, naming the file."""
    from loaders.avd import AVDScan
    from loaders.errors import BadInputError

    base = planted[0]
    with pytest.raises(BadInputError, match=r"annotations.json: image key .* refused"):
        AVDScan(base / "avd", "Home_005_1", frames=False)
    assert not os.path.exists(tmp_path / "PWNED.jpg")


def _write_in_worker(target: str) -> str:
    """Runs in a pool worker: write one file, say what happened."""
    from pipeline.infra.cache import OutsideFolderError, write_bytes

    try:
        write_bytes(target, b"x")
    except OutsideFolderError as e:
        return f"refused: {e}"
    return "written"


def test_pool_workers_write_under_the_stage_folder_too(tmp_path):
    """Spawned workers start with no confinement of their own: the pool hands them the stage's."""
    from pipeline.infra.cache import confined_writes
    from pipeline.infra.workers import worker_pool

    stage, outside = tmp_path / "run" / ".data.tmp", tmp_path / "outside"
    stage.mkdir(parents=True)
    outside.mkdir()
    targets = [str(stage / "ok" / "a.bin"), str(outside / "PWNED"), str(stage / ".." / ".." / "PWNED")]
    with confined_writes(stage), worker_pool(2) as pool:
        said = list(pool.map(_write_in_worker, targets))
    assert said[0] == "written" and (stage / "ok" / "a.bin").is_file()
    assert all(s.startswith("refused:") and "outside the stage's temporary folder" in s for s in said[1:]), said
    assert not list(outside.iterdir()) and not (tmp_path / "PWNED").exists()
    with worker_pool(1) as pool:  # no stage running: workers write where told, as the parent would
        assert list(pool.map(_write_in_worker, [str(outside / "free.bin")])) == ["written"]
