"""models.instance_term: the models stage writes the instance bank beside the default one (here
every class is one object, so no class gets a term and the records say why), and the evaluate
stage's loader puts it under ``INSTANCE_BANK``."""
import json

import numpy as np
import pytest

from pipeline.evaluation.grid.population import DEFAULT, INSTANCE_BANK
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.gp_instance_fit import NO_TERM
from stages.evaluate import load_banks
from stages.framework.registry import STAGES
from stages.framework.runner import run_stage
from tests.stages.test_models_stage import CLASSES, write_features

pytestmark = pytest.mark.slow  # runs a real stage (make test-fast skips it)


def test_models_stage_writes_the_instance_bank(tmp_config):
    cfg = tmp_config({"models": {"classes": CLASSES, "n_components": 2, "restarts": 0, "instance_term": True},
                      "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]]}})
    feat = cfg.stage_dir("features")
    write_features(feat / "bigbird.parquet")
    (feat / "manifest.json").write_text(json.dumps({"stage": "features", "key": "fake"}))
    run_stage(cfg, STAGES["models"], "k", {}, device="cpu", threads=1)
    out = cfg.stage_dir("models")
    index = json.loads((out / "instance" / "index.json").read_text())
    assert all(d["instance_note"] == NO_TERM for d in index["diagnostics"]) and index["instances"] == {
        c: [c] for c in CLASSES}
    banks, _ = load_banks(out, ())
    inst, plain = banks[INSTANCE_BANK], banks[DEFAULT]
    assert isinstance(inst, InstanceGPClassModels) and not np.any(inst.instance_amplitude)
    for name in ("amplitude", "length_scale", "noise", "mean"):
        assert np.array_equal(getattr(inst, name), getattr(plain, name))
