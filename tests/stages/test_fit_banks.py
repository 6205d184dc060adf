"""The fit-only banks of ``evaluate.fit_spaces``: the models stage fits one bank per listed space
that no other bank holds (beside the ablations', named in the index's ``fit_banks``, not its
``ablations``: no cell runs on them), and the evaluate stage finds each one there, or says to rerun
the models stage."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.infra.config import fit_only_banks
from pipeline.method.gp_files import load_bank, read_bank_index
from pipeline.evaluation.grid.banks import fit_bank_loaders
from stages.framework.registry import STAGES
from stages.framework.runner import read_manifest, run_stage
from tests.stages.test_models_stage import CLASSES, write_features

pytestmark = pytest.mark.slow  # runs the models stage

LOG, CLR = "models.score_space=log", "models.score_space=clr"


def test_the_models_stage_fits_each_fit_only_bank_once(tmp_config):
    cfg = tmp_config({"models": {"classes": CLASSES, "n_components": 2, "restarts": 0},
                      "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]], "ablations": [CLR],
                                   "fit_spaces": ["probability", "log", "clr"]}})
    feat = cfg.stage_dir("features")
    write_features(feat / "bigbird.parquet")
    (feat / "manifest.json").write_text(json.dumps({"stage": "features", "key": "fake"}))
    run_stage(cfg, STAGES["models"], "k", {}, device="cpu", threads=1)
    out = cfg.stage_dir("models")
    index = read_bank_index(out)
    # probability is the run's own bank and clr the ablation's: only log is fitted for the table
    assert list(index["fit_banks"]) == [LOG] and list(index["ablations"]) == [CLR]
    assert "1 fit-only bank(s) (log)" in read_manifest(cfg, "models")["summary"]
    sub = read_bank_index(out / index["fit_banks"][LOG])
    assert sub["fit_only"] is True and sub["ablation"] == LOG
    main, log = load_bank(out), load_bank(out / index["fit_banks"][LOG])
    assert log.classes == main.classes and list(log.components) == list(main.components)
    # the same training views in the other space: each log target is the mean of the passes' logs,
    # so at most the log of the main bank's mean probability (Jensen; float32 scores: 1e-6 slack)
    assert log.meta["score_space"]["space"] == "log"
    assert main.meta.get("score_space", {}).get("space", "probability") == "probability"
    for Ym, Yl in zip(main.Y, log.Y):
        assert Yl.shape == Ym.shape and (Yl < 0).all()
        assert (Yl <= np.log(Ym) + 1e-6).all()
    # the evaluate stage loads it from the index; without it in the index it names the key
    loaders = fit_bank_loaders(out, cfg, index)
    assert list(loaders) == list(fit_only_banks(cfg)) == [LOG]
    assert loaders[LOG]().meta["score_space"]["space"] == "log"
    with pytest.raises(ValueError, match="evaluate.fit_spaces.*rerun the models stage"):
        fit_bank_loaders(out, cfg, {**index, "fit_banks": {}})
