"""The scans written by one process and by forked writers (``data.real_imagery.workers``) are the
same files, byte for byte, with the sensor model on (each frame draws its noise from its own
stream): the real data, three COIL objects on two real AVD scans."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.loaders.realdata import need


def _written(tmp: Path, workers: int, monkeypatch) -> dict[str, str]:
    from loaders.errors import SkipPolicy
    from loaders.real_imagery import write as W
    from pipeline.infra.config import load_config
    from tests.conftest import ROOT

    real = need("coil100").parent
    cfg = load_config(ROOT / "configs" / "real.toml", {
        "run": {"artifacts": str(tmp / "artifacts")},
        "data": {"coil_root": str(real / "coil100"), "avd_root": str(need("avd")), "avd_frames_root": str(need("avd_frames")),
                 "scans": ["Home_005_1", "Home_014_1"],
                 "real_imagery": {"objects": [2, 3, 4], "workers": workers}},
        "evaluate": {"n_candidates": 2}})
    seen = []
    # the count asked for, not the cores' cap: the forked route runs on a one-core machine too
    monkeypatch.setattr(W, "writer_count", lambda cfg, key, n: seen.append(n) or n)
    W.write_real_imagery(cfg, tmp / "bigbird", tmp / "avd", tmp / "truth.json", SkipPolicy(True))
    assert seen == [workers]
    return {p.relative_to(tmp).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(tmp.rglob("*")) if p.is_file() and "artifacts" not in p.parts}


def _start_cv2_pool() -> None:
    """OpenCV's worker threads running in this process, as after any earlier stage or test that
    resized an image: a forked writer must not touch the pool it inherits without its threads."""
    import cv2
    import numpy as np

    cv2.setNumThreads(2)
    cv2.resize(np.zeros((2000, 2000, 3), np.uint8), (1000, 1000), interpolation=cv2.INTER_AREA)


def test_forked_scan_writers_write_the_same_bytes(tmp_path, monkeypatch):
    _start_cv2_pool()
    one = _written(tmp_path / "one", 1, monkeypatch)
    two = _written(tmp_path / "two", 2, monkeypatch)
    frames = [k for k in one if "/jpg_rgb/" in k]
    assert len(frames) > 100 and any(k.startswith("avd/Home_014_1/") for k in frames)
    assert not any(".placeholder" in k for k in one)   # the shared black frame is removed after linking
    assert two == one


def test_a_failing_scan_writer_stops_the_stage(tmp_path, monkeypatch):
    from loaders.real_imagery import scans as S

    def broken(job, *args):
        raise RuntimeError(f"render failed in {job[0].scan.scan}")

    monkeypatch.setattr(S, "_write_scan", broken)
    with pytest.raises(RuntimeError, match="render failed in Home_0"):
        _written(tmp_path / "x", 2, monkeypatch)
