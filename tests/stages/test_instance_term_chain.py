"""``models.instance_term = true`` through the models and evaluate stages on the smoke upstream:
the models stage fits the instance term's provider into ``models/instance_term/`` and records its
digest, evaluate hands it to the cells as that provider's models (no stage names it), and since
every smoke class is one object (no class can fit a term) the two instance methods equal With
Uncertainty and Model Based on every result row."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pipeline.method.names import MB_INSTANCE, MODEL_BASED, WITH_UNCERTAINTY, WU_INSTANCE
from tests.support.shared_upstream import DEVICE, copy_upstream, smoke_config, smoke_upstream

pytestmark = pytest.mark.slow  # reruns the smoke chain's models and evaluate stages

SMALL = {"evaluate": {"ablations": [], "attribution": False, "tracks_per_target": 1, "bootstrap": 100,
                      "randomized": {"sigmas_m": [0.3]}}, "plan": {"enabled": False}}


def test_the_instance_term_runs_through_models_and_evaluate_as_a_methods_own_model(tmp_path_factory, tmp_path):
    from stages.framework.runner import ensure

    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path / "artifacts")
    cfg = smoke_config(art, {**SMALL, "models": {"instance_term": True}})
    ensure(cfg, "evaluate", device=DEVICE)
    run = art / "smoke"
    index = json.loads((run / "models" / "instance_term" / "index.json").read_text())
    assert index["diagnostics"] and not any(d["instance_term"] for d in index["diagnostics"])
    assert index["candidate_sets"] == json.loads((run / "models" / "index.json").read_text())["candidate_sets"]
    extra = json.loads((run / "models" / "manifest.json").read_text())["extra"]
    assert extra["instance_term_without"] == len(index["diagnostics"]) and extra["instance_term_fingerprint"]
    pop = json.loads((run / "evaluate" / "summary.json").read_text())["population"]
    assert {WU_INSTANCE, MB_INSTANCE} <= set(pop["methods"])
    rows = pd.read_parquet(run / "evaluate" / "results.parquet")
    key = [c for c in ("variant", "experiment", "setting", "target", "track", "realization", "step")
           if c in rows.columns]
    for new, old in ((WU_INSTANCE, WITH_UNCERTAINTY), (MB_INSTANCE, MODEL_BASED)):
        a = rows[rows["method"] == new].sort_values(key).reset_index(drop=True)
        b = rows[rows["method"] == old].sort_values(key).reset_index(drop=True)
        assert len(a) == len(b) > 0
        num = [c for c in a.columns if c != "method" and pd.api.types.is_float_dtype(a[c])]
        np.testing.assert_array_equal(a[num].to_numpy(), b[num].to_numpy())
