"""``evaluate.fit_spaces``: score spaces whose model bank is fitted for the test-domain fit table
only. Bad values are refused naming the key; a space that another bank of the run already holds
(the run's own, a ``models.score_space`` ablation's) is not fitted again; the models stage's key and
the cost model count the banks."""
from __future__ import annotations

import pytest

from pipeline.infra.config import ConfigError, fit_only_banks, load_config
from pipeline.infra.cost import fixed_evaluate_parts, models_terms
from stages.framework.registry import STAGES
from tests.conftest import DEFAULT_CONFIG, ROOT


def _cfg(**evaluate):
    return load_config(DEFAULT_CONFIG, {"evaluate": evaluate})


@pytest.mark.parametrize("value, words", [
    (["log", "lg"], "'evaluate.fit_spaces[1]' = 'lg' is not one of"),
    (["clr", "clr"], "'evaluate.fit_spaces' lists 'clr' more than once"),
    ("log", "'evaluate.fit_spaces' must be a list"),
    ([3], "evaluate.fit_spaces[0]"),
])
def test_bad_values_are_refused_naming_the_key(value, words):
    with pytest.raises(ConfigError) as e:
        _cfg(fit_spaces=value)
    assert words in str(e.value)


def test_a_space_another_bank_holds_is_not_fitted_twice():
    assert fit_only_banks(_cfg()) == ()   # the default lists none
    cfg = load_config(DEFAULT_CONFIG, {"models": {"score_space": "logit"},
                                       "evaluate": {"fit_spaces": ["log", "logit", "clr", "probability"],
                                                    "ablations": ["models.score_space='clr'",
                                                                  "evaluate.test_domain_variance=cross_fit"]}})
    # logit: the run's own; clr: an ablation's (quoted as TOML may write it); probability stays
    assert fit_only_banks(cfg) == ("models.score_space=log", "models.score_space=probability")


def test_the_models_stage_declares_the_key_and_the_cost_model_counts_the_banks():
    assert "evaluate.fit_spaces" in STAGES["models"].sections
    base, more = _cfg(), _cfg(fit_spaces=["log", "clr"])
    fits = [models_terms(c)[0] for c in (base, more)]
    assert "evaluate.fit_spaces" in fits[1].keys and "x 3 bank(s)" in fits[1].what
    assert fits[1].seconds == pytest.approx(3 * fits[0].seconds)
    dom = [next(t for t in fixed_evaluate_parts(c, 4, 2) if "test-domain fit" in t.what) for c in (base, more)]
    assert "x 3 model bank(s)" in dom[1].what and "x 1 model bank(s)" in dom[0].what


def test_every_shipped_config_on_real_scores_lists_the_log_type_spaces():
    for path in sorted((ROOT / "configs").glob("real*.toml")) + [ROOT / "configs" / "avd.toml"]:
        cfg = load_config(path)
        spaces = {a.split("=", 1)[1] for a in fit_only_banks(cfg)} | {cfg.models.score_space}
        assert {"log", "logit", "clr"} <= spaces, path.name
