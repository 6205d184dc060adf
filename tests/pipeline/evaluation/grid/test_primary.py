"""The one primary comparison declared before the run (``evaluate.primary``): validated, read on
the named setting only, and outside any multiplicity family."""
import dataclasses

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.grid import population as P
from pipeline.evaluation.grid.primary import check_declared, declared_block, paired_table
from pipeline.infra.config import ConfigError, EvaluateConfig, load_config
from pipeline.infra.config.evaluation import PrimaryConfig


def _ev(**primary):
    return dataclasses.replace(EvaluateConfig(), experiments=("biased", "randomized"), bootstrap=200,
                               randomized=dataclasses.replace(EvaluateConfig().randomized, sigmas_m=(0.3,)),
                               primary=PrimaryConfig(**primary))


def _table(ev, shift_biased: float, shift_randomized: float, seed=0):
    """Cells of two methods on 8 targets x 4 tracks in each setting: model_based's value plus a
    planted shift per setting for with_uncertainty."""
    rng = np.random.default_rng(seed)
    rows = []
    shift = {"biased": shift_biased, "randomized": shift_randomized}
    for s in P.population_settings(ev):
        for t in range(8):
            for tr in range(4):
                base = rng.uniform(0.2, 0.6)
                for m, v in (("model_based", base), ("with_uncertainty", base + shift[s.experiment])):
                    rows.append({"variant": P.DEFAULT, "target": f"t{t}", "scan": "s0", "track": tr,
                                 "setting": s.label, "method": m, "confident_error_final": v})
    return pd.DataFrame(rows)


def test_the_declared_setting_alone_is_read_and_left_unadjusted():
    ev = _ev(setting="biased")
    out = declared_block(ev, _table(ev, -0.2, 0.1))
    rec = out["record"]
    assert rec["comparison"] == "with_uncertainty-model_based" and out["adjusted"] is False
    assert rec["value"] == pytest.approx(-0.2) and rec["outcome"] == "better"   # fewer confident errors
    assert "outcome_holm" not in rec and "family" not in rec                   # no multiplicity family
    pooled = declared_block(dataclasses.replace(ev, primary=PrimaryConfig(setting="all")), _table(ev, -0.2, 0.1))
    assert pooled["record"]["value"] == pytest.approx(-0.05)                   # the mean over both settings
    assert len(pooled["settings"]) == 2


def test_a_setting_the_run_lacks_is_said_not_measured():
    ev = _ev(setting="biased_randomized")
    out = declared_block(ev, _table(ev, -0.2, 0.1))
    assert out["record"] is None and "biased_randomized" in out["missing"]


def test_bad_declarations_name_the_key():
    with pytest.raises(ConfigError, match="evaluate.primary.metric"):
        check_declared(_ev(metric="no_such_metric"))
    with pytest.raises(ConfigError, match="evaluate.primary.methods"):
        check_declared(_ev(methods=("with_uncertainty", "nobody")))
    with pytest.raises(ConfigError, match="evaluate.attribution"):
        check_declared(dataclasses.replace(_ev(methods=("with_uncertainty_poses_only", "model_based")),
                                           attribution=False))


def test_the_schema_refuses_a_pair_that_is_not_one_and_a_setting_not_run(tmp_path):
    for body, key in (('methods = ["model_based", "model_based"]', "evaluate.primary.methods"),
                      ('setting = "biased_randomized"', "evaluate.primary.setting"),
                      ('setting = "nowhere"', "evaluate.primary.setting")):
        p = tmp_path / "c.toml"
        p.write_text(f"[evaluate.primary]\n{body}\n")
        with pytest.raises(ConfigError, match=key):
            load_config(p)


def test_the_primary_enters_the_evaluate_key(tmp_path):
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text("[evaluate.primary]\nmetric = 'correct_final'\n")
    b.write_text("[evaluate.primary]\nmetric = 'confident_error_final'\n")
    assert load_config(a).section_hash("evaluate") != load_config(b).section_hash("evaluate")


def test_the_paired_table_holds_one_difference_per_track():
    ev = _ev(setting="all")
    t = _table(ev, -0.2, 0.1)
    d = paired_table(t, "with_uncertainty", "model_based", "confident_error_final",
                     [s.label for s in P.population_settings(ev)])
    assert len(d) == 8 * 4 and np.allclose(d["d"], -0.05)


def test_the_declared_pair_leaves_only_the_family_of_its_own_cells():
    from pipeline.evaluation.grid.primary import declared_pair

    ev = _ev(setting="biased")
    labels = [s.label for s in P.population_settings(ev)]
    biased = setting_labels_of(ev, "biased")
    assert declared_pair(ev, biased) == {("with_uncertainty-model_based", "confident_error_final")}
    assert declared_pair(ev, labels) == set()          # every setting pooled: another statistic, stays in
    every = dataclasses.replace(ev, primary=PrimaryConfig(setting="all"))
    assert declared_pair(every, labels) and not declared_pair(every, biased)


def setting_labels_of(ev, experiment):
    return [s.label for s in P.population_settings(ev) if s.experiment == experiment]
