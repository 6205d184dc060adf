"""A key that an extension adds to its parent section (``own.Key``; the instance term's provider
declares ``[models] instance_term``): read and checked like a built-in key, written by ``to_dict``
as a key of the parent (so a run's recorded config and the section hash keep their shape), in the
models stage's key, listed by ``--help``, and a Key of another type is refused at registration."""
from __future__ import annotations

import pytest

from pipeline.infra.config import ConfigError, load_config, to_dict
from pipeline.infra.config.fields import setting
from pipeline.infra.config.own import Key, register_sections
from tests.conftest import ROOT

SMOKE = ROOT / "configs" / "smoke.toml"


@pytest.mark.parametrize("text, message", [
    ("[models]\ninstance_term = 3", "'models.instance_term' must be true or false, got 3"),
    ("[models.instance_term]\nx = 1", "'models.instance_term' must be true or false, got {'x': 1}"),
    ("[models]\ninstance_prior = \"beta\"", "'models.instance_prior' = 'beta' is not one of 'none', 'split'"),
    ("[models]\ninstance_prior_alpha = 0.0", "'models.instance_prior_alpha' = 0.0 is below the minimum 0.001"),
])
def test_a_bad_value_is_refused_naming_the_key(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert str(e.value) == f"{path}: {message}"


def test_the_key_reads_writes_and_hashes_as_a_key_of_its_parent(tmp_path):
    base = load_config(SMOKE)
    on = load_config(SMOKE, {"models": {"instance_term": True}})
    assert base.models.instance_term is False and on.models.instance_term is True
    assert to_dict(base)["models"]["instance_term"] is False and to_dict(on)["models"]["instance_term"] is True
    assert on != base and on.section_hash("models") != base.section_hash("models")
    assert on.section("models.instance_term") is True
    from stages.commands.cli import config_keys_help

    assert "  models.instance_term = False: also fit class models with an instance term" in config_keys_help("models")
    assert config_keys_help("models.instance_term").startswith("  models.instance_term = False")


def test_a_key_must_be_a_scalar_with_a_setting_field():
    with pytest.raises(TypeError, match="must be a Key of bool, int, float or str"):
        register_sections("bad", {"models.bad": Key(list, setting(factory=list))}, module=__name__)
