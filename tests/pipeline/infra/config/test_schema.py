"""The JSON Schema for editors (``viewfuse schema``) is written from the loader's declarations: every
shipped config validates against it, and an unknown key, a value out of range, a choice not
offered and a wrong type each fail it, as the loader refuses them."""
import json
import tomllib
from pathlib import Path

import pytest

from pipeline.infra.config import ConfigError, load_config
from pipeline.infra.config.schema import json_schema
from stages.commands.cli import main

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema validates the written schema")
ROOT = Path(__file__).resolve().parents[4]


def _errors(table: dict) -> list[str]:
    return [e.message for e in jsonschema.Draft202012Validator(json_schema()).iter_errors(table)]


def test_every_shipped_config_validates():
    for path in sorted((ROOT / "configs").glob("*.toml")):
        assert _errors(tomllib.loads(path.read_text())) == [], path.name


@pytest.mark.parametrize("table, part", [
    ({"evaluate": {"track_lenght": 9}}, "track_lenght"),
    ({"run": {"threads": 999}}, "999"),
    ({"evaluate": {"candidates": "some"}}, "some"),
    ({"plan": {"budget": "ten"}}, "ten"),
])
def test_what_the_loader_refuses_the_schema_refuses(tmp_path, table, part):
    assert any(part in e for e in _errors(table)), _errors(table)
    cfg = tmp_path / "c.toml"
    lines = [f"[{s}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in kv.items()) for s, kv in table.items()]
    cfg.write_text("".join(lines))
    with pytest.raises(ConfigError):
        load_config(cfg)


def test_the_command_writes_the_schema(tmp_path):
    out = tmp_path / "viewfuse.schema.json"
    assert main(["schema", "--out", str(out)]) == 0
    schema = json.loads(out.read_text())
    assert schema["properties"]["evaluate"]["properties"]["track_length"]["type"] == "integer"
    assert schema["properties"]["evaluate"]["additionalProperties"] is False
