"""The ``[plan]`` section: defaults, ranges and unknown keys are errors naming the file and key,
and the evaluate stage hashes it (an edit reruns evaluate, not the stages above)."""
import pytest

from pipeline.infra.config import ConfigError, load_config
from stages.framework.registry import STAGES


def write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_defaults(tmp_path):
    plan = load_config(write(tmp_path, "")).plan
    assert (plan.enabled, plan.budget, plan.horizon, plan.confidence) == (True, 10, 1, 0.9)


@pytest.mark.parametrize("text, key", [
    ("[plan]\nbudget = 1\n", "plan.budget"), ("[plan]\nhorizon = 0\n", "plan.horizon"),
    ("[plan]\nconfidence = 1.5\n", "plan.confidence"), ("[plan]\neig_samples = 1\n", "plan.eig_samples"),
    ("[plan]\nstarts = 0\n", "plan.starts"), ("[plan]\nsigma_m = -0.1\n", "plan.sigma_m"),
    ("[plan]\nbudgett = 3\n", "plan.budgett"), ("[plan]\nenabled = 3\n", "plan.enabled"),
])
def test_bad_values_name_the_file_and_key(tmp_path, text, key):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_config(p)
    assert key in str(e.value) and str(p) in str(e.value)


def test_evaluate_declares_the_section():
    spec = STAGES["evaluate"]
    assert "plan" in spec.sections
    assert all("plan" not in STAGES[s].sections for s in ("data", "features", "models", "report"))
