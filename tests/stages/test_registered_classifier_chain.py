"""A classifier registered from tests/ (no product code edited) runs the classifier and features
stages of a tiny synthetic chain: its card names it, and the feature tables hold its scores."""
import json

import numpy as np
import pytest
import torch

from pipeline.infra.config import merge
from pipeline.scoring.features import read_features
from pipeline.scoring.weight_files import save_state_dict_npz
from tests.pipeline.scoring.test_classifier_registry import ToyNet
from tests.stages.test_features_stage import TINY

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)


def test_a_registered_toy_classifier_runs_the_classifier_and_features_stages(tmp_path):
    from pipeline.infra.config import load_config
    from pipeline.scoring.classifiers import check_config
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    torch.manual_seed(0)
    npz = tmp_path / "toy.npz"
    sha = save_state_dict_npz(ToyNet(7, 0.4), npz)
    tiny = merge(TINY, {"classifier": {"arch": "toy_from_tests", "weights": "path", "path": str(npz),
                                       "dropout": 0.4},
                        "run": {"artifacts": str(tmp_path / "artifacts")}})
    cfg = load_config(DEFAULT_CONFIG, tiny)
    check_config(cfg.classifier, "tiny")
    ensure(cfg, "features", device="cpu")
    card = json.loads((cfg.stage_dir("classifier") / "card.json").read_text())
    assert card["arch"] == "toy_from_tests" and card["weights_sha256"] == sha and card["num_classes"] == 7
    for name in ("bigbird.parquet", "avd.parquet"):
        table, scores, meta = read_features(cfg.stage_dir("features") / name)
        assert scores.shape[1] == 7 and len(table) > 0
        np.testing.assert_allclose(scores.sum(1), 1.0, atol=1e-5)
        passes = table["pass"].to_numpy()
        assert (passes == 0).any() and (passes > 0).any()   # the deterministic pass and dropout samples
        det, mc = scores[passes == 0], scores[passes > 0]
        assert np.abs(mc.mean(0) - det.mean(0)).max() < 0.5 and mc.std(0).max() > 0  # samples vary
