"""The evaluate stage's object estimate on the synthetic stand-in: within 5 cm of the truth."""
import json

import numpy as np
import pytest

from pipeline.scene.rays import bearing_rays, intersect_rays

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


@pytest.fixture(scope="module")
def small_scan(tmp_path_factory):
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    tmp = tmp_path_factory.mktemp("loc")
    cfg = load_config(DEFAULT_CONFIG, {
        "run": {"artifacts": str(tmp / "artifacts")},
        "data": {"scans": ["Home_001_1"], "synthetic": {"instances": ["aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "crystal_hot_sauce", "honey_bunches_of_oats_honey_roasted", "mahatma_rice", "pepto_bismol"],
                               "instances_per_scan": 0, "avd_box_jitter_px": 0, "occluders": 0, "distractors": 0, "angle_step_deg": 120, "bigbird_width": 160, "bigbird_height": 128,
                               "avd_width": 320, "avd_height": 180}},
    })
    ensure(cfg, "data")
    return cfg


def test_ray_intersection_finds_each_instance(small_scan):
    from loaders.avd import AVDScan
    from stages.framework.roots import data_roots

    cfg = small_scan
    _, avd_root = data_roots(cfg)
    scan = AVDScan(avd_root, cfg.data.scans[0])
    truth = json.loads((cfg.stage_dir("data") / "truth.json").read_text())
    K = scan.intrinsics()
    checked = 0
    for name, obj in truth["instances"].items():
        views = scan.boxes_of(name, max_difficulty=4)
        if len(views) < 3:
            continue
        cam = np.array([im.position for im, _ in views])
        heading = np.array([im.heading for im, _ in views])
        cx = np.array([0.5 * (b.x0 + b.x1) for _, b in views])
        est = intersect_rays(*bearing_rays(cam, heading, cx, K[0, 0], K[0, 2]))
        err = np.linalg.norm(est - np.asarray(obj["position"]))
        assert err < 0.05, f"{name}: object estimate {err * 100:.1f} cm from the truth"
        checked += 1
    assert checked >= 2
