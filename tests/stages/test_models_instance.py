"""models.instance_term: the models stage fits the instance term's provider beside the default bank
(``models/instance_term/``; here every class is one object, so no class gets a term and the
records say why) and records its digest; the evaluate stage's loader hands it over as that
provider's models, on the default bank's plan, and the contrast arm's folder gets none."""
import json

import numpy as np
import pytest

from pipeline.method.gp_files import load_bank
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.gp_instance_fit import NO_TERM
from pipeline.method.methods.instance_term import INSTANCE_TERM
from pipeline.evaluation.grid.banks import load_provided
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
    index = json.loads((out / INSTANCE_TERM / "index.json").read_text())
    assert all(d["instance_note"] == NO_TERM for d in index["diagnostics"]) and index["instances"] == {
        c: [c] for c in CLASSES}
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["extra"][f"{INSTANCE_TERM}_without"] == len(index["diagnostics"])
    assert manifest["extra"][f"{INSTANCE_TERM}_with_term"] == 0
    provided = load_provided(out, cfg)
    assert set(load_provided(out, cfg, variant=True)) == set(provided) - {INSTANCE_TERM}
    inst, plain = provided[INSTANCE_TERM].models, load_bank(out)
    assert isinstance(inst, InstanceGPClassModels) and not np.any(inst.instance_amplitude)
    assert manifest["extra"][f"{INSTANCE_TERM}_fingerprint"] == inst.digest()
    for name in ("amplitude", "length_scale", "noise", "mean"):
        assert np.array_equal(getattr(inst, name), getattr(plain, name))
