"""Reading a run folder that ``viewfuse compare`` did not write: safely, and checked.

``compare`` is pointed at folders from anywhere (a colleague's run, a download), so each file is
read as untrusted input:

- a regular file only (``loaders.files.checked_file``: a FIFO would block forever, a symlink to
  ``/dev/zero`` would be read until memory runs out), no larger than its cap, checked before reading;
- JSON nested no deeper than ``MAX_DEPTH`` (a 100,000-deep file would otherwise end in a
  RecursionError inside the parser or in ``flatten``);
- the structure compare relies on checked against a small schema (``SUMMARY_SCHEMA``,
  ``MANIFEST_SCHEMA``), so a wrong type is an error naming the run, the file and the field, never an
  AttributeError deep in the table code.

A bad summary stops compare (there is nothing to compare without it); a bad manifest only loses
that stage's config, and the output says so (``manifest_sections`` returns the reason).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from loaders.errors import BadInputError
from loaders.files import checked_file
from pipeline.infra.nesting import depth
from pipeline.infra.outputs import name as out_name
from reports.shared.numbers import fmt, plain

# Real summaries are ~3 MB (the paper-grade evaluate), manifests a few kB: the caps leave room
# for growth and stop a multi-GB file before it is read.
MAX_SUMMARY_BYTES = 64 * 2**20
MAX_MANIFEST_BYTES = 8 * 2**20
MAX_DEPTH = 64  # real summaries nest 6 deep


class RunFileError(ValueError):
    """A run's file that cannot be used; the message names the file and the field."""


def read_json(path: Path, max_bytes: int, what: str) -> Any:
    """The JSON in ``path``, read only if it is a regular file of at most ``max_bytes`` and
    nested at most ``MAX_DEPTH`` deep; RunFileError otherwise (FileNotFoundError when absent)."""
    if not os.path.lexists(path):
        raise FileNotFoundError(path)
    try:
        checked_file(path, what=what)
    except BadInputError as e:
        raise RunFileError(f"{path}: {e.problem}") from None
    size = os.stat(path).st_size
    if size > max_bytes:
        raise RunFileError(f"{path}: {what} is {fmt(size / 2**20)} MiB, above the {plain(max_bytes / 2**20)} MiB "
                           "a run writes; not read")
    with open(path, "rb") as f:
        data = f.read(max_bytes + 1)  # the file may grow between stat and read
    if len(data) > max_bytes:
        raise RunFileError(f"{path}: {what} grew above {plain(max_bytes / 2**20)} MiB while read; not read")
    try:
        value = json.loads(data)
    except RecursionError:
        raise RunFileError(f"{path}: {what} is nested deeper than {MAX_DEPTH} levels; not read") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RunFileError(f"{path}: {what} is not valid JSON ({e})") from None
    if depth(value) > MAX_DEPTH:
        raise RunFileError(f"{path}: {what} is nested deeper than {MAX_DEPTH} levels; not read")
    return value


# -- schema ------------------------------------------------------------------------------------------
# A schema is a type name, or ("object", {key: schema}) for an object whose listed keys (all
# optional unless in REQUIRED) have those schemas, or ("map", schema) for an object of any keys
# whose values share one schema, or ("list", schema).
NUMBER = "number or null"
ESTIMATE = ("object", {"value": NUMBER, "ci_low": NUMBER, "ci_high": NUMBER})
VERDICT_ROW = ("object", {"comparison": "string", "metric": "string", "outcome": "string",
                          "value": NUMBER, "ci_low": NUMBER, "ci_high": NUMBER})
RECORD = ("object", {"comparison": "string", "metric": "string", "outcome": "string",
                     "value": NUMBER, "lo": NUMBER, "hi": NUMBER, "outcome_holm": "string",
                     "lo_holm": NUMBER, "hi_holm": NUMBER, "level_holm": NUMBER, "p_holm": NUMBER})
REQUIRED = {id(VERDICT_ROW): ("comparison", "metric", "outcome"),   # keys every verdict row has
            id(RECORD): ("comparison", "metric", "outcome")}
SUMMARY_SCHEMA = ("object", {"population": ("object", {
    "pooled": ("map", ("map", ESTIMATE)),
    "paired": ("map", ("map", "any")),
    "records": ("list", RECORD),
    "verdict_table": ("list", VERDICT_ROW),   # summaries before the records
    "cells": ("list", "any"),
}), "planning": ("object", {"pooled": ("map", ("map", ESTIMATE)), "paired": ("map", ("map", ESTIMATE)),
                            "planners": ("list", "string")})})
MANIFEST_SCHEMA = ("object", {"parts": ("object", {"sections": ("map", "any")})})

_NAMES = {dict: "an object", list: "a list", str: "a string", bool: "a boolean", int: "a number",
          float: "a number", type(None): "null"}


def _found(v: Any) -> str:
    text = json.dumps(v, default=str)
    return f"{_NAMES.get(type(v), type(v).__name__)} {text[:40] + ('…' if len(text) > 40 else '')}"


def check(value: Any, schema: Any, where: str = "") -> None:
    """RunFileError naming the first field (dotted path) that does not fit ``schema``."""
    field = where or "the top level"
    if schema == "any":
        return
    if schema == NUMBER:
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise RunFileError(f"{field}: expected a number or null, found {_found(value)}")
        return
    if schema == "string":
        if not isinstance(value, str):
            raise RunFileError(f"{field}: expected a string, found {_found(value)}")
        return
    kind, inner = schema
    if kind == "list":
        if not isinstance(value, list):
            raise RunFileError(f"{field}: expected a list, found {_found(value)}")
        for i, v in enumerate(value):
            check(v, inner, f"{where}[{i}]")
        return
    if not isinstance(value, dict):
        raise RunFileError(f"{field}: expected an object, found {_found(value)}")
    sub = (lambda k: f"{where}.{k}" if where else str(k))
    if kind == "map":
        for k, v in value.items():
            check(v, inner, sub(k))
        return
    for k in REQUIRED.get(id(schema), ()):
        if k not in value:
            raise RunFileError(f"{field}: the field '{k}' is missing")
    for k, s in inner.items():
        if k in value:
            check(value[k], s, sub(k))



def read_summary(path: Path) -> Any:
    """summary.json, read safely and checked against ``SUMMARY_SCHEMA``; RunFileError names the
    file and the field."""
    value = read_json(path, MAX_SUMMARY_BYTES, out_name("evaluate", "summary"))
    try:
        check(value, SUMMARY_SCHEMA)
    except RunFileError as e:
        raise RunFileError(f"{path}: {e}") from None
    return value


def manifest_sections(path: Path) -> tuple[dict | None, str | None]:
    """(the config sections a stage manifest recorded, None) or (None, why it cannot be used)."""
    try:
        m = read_json(path, MAX_MANIFEST_BYTES, "manifest")
        check(m, MANIFEST_SCHEMA)
    except FileNotFoundError:
        return None, "missing"
    except RunFileError as e:
        return None, str(e).removeprefix(f"{path}: ")
    return ((m.get("parts") or {}).get("sections") or {}), None


# -- terminal ------------------------------------------------------------------------------------------
def printable(text: Any) -> str:
    """``text`` with control and format characters (terminal escapes, bidi overrides) shown as
    ``\\x1b``-style escapes, so a value from a run folder cannot drive the terminal."""
    s = str(text)
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in s)
