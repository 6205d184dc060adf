"""A JSON Schema of the config file, written from the same declarations the loader checks
(``setting``: type, range, choices, doc; the sections extensions declare), for editors that
complete and check TOML keys against a schema (``viewfuse schema``). The loader stays the judge:
cross-key checks (``checks.py``) and the sections of dataset sources other than the default's
are not in the schema."""
from __future__ import annotations

import dataclasses
import typing
from typing import Any

from pipeline.infra.config.own import own_items, registered
from pipeline.infra.config.root import Config

_SCALARS = {bool: "boolean", int: "integer", float: "number", str: "string"}


def _value(tp: Any, f: dataclasses.Field | None, default: Any) -> dict:
    md = f.metadata if f is not None else {}
    if typing.get_origin(tp) is tuple:
        items = _value(typing.get_args(tp)[0], f, None)
        items.pop("description", None)
        out: dict = {"type": "array", "items": items}
        if md.get("words"):
            out = {"anyOf": [out, {"enum": list(md["words"])}]}
    else:
        out = {"type": _SCALARS.get(tp, "string")}
        if md.get("choices"):
            out["enum"] = list(md["choices"])
        if md.get("lo") is not None:
            out["minimum"] = md["lo"]
        if md.get("hi") is not None:
            out["maximum"] = md["hi"]
    if md.get("doc"):
        out["description"] = md["doc"]
    if default is not None:
        out["default"] = list(default) if isinstance(default, tuple) else default
    return out


def _section(obj: Any, prefix: str) -> dict:
    hints = typing.get_type_hints(type(obj))
    props: dict[str, dict] = {}
    for f in dataclasses.fields(obj):
        if f.metadata.get("internal"):
            continue
        value = getattr(obj, f.name)
        props[f.name] = _section(value, f"{prefix}{f.name}.") if dataclasses.is_dataclass(value) \
            else _value(hints[f.name], f, value)
    for name, value in own_items(obj):   # the sections and keys extensions declared here
        if dataclasses.is_dataclass(value):
            props[name] = _section(value, f"{prefix}{name}.")
        else:
            props[name] = _value(type(value), registered(prefix[:-1])[name].field, value)
    return {"type": "object", "properties": props, "additionalProperties": False}


def json_schema() -> dict:
    """The schema of a config file with the built-in and registered sections, defaults included."""
    root = _section(Config(), "")
    root["properties"]["extends"] = {"type": "string",
                                     "description": "a config file this one starts from (its keys overridden here)"}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "viewfuse config", **root}
