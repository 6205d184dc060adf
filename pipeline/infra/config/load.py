"""Loading a TOML config: decode, type-check and range-check every key against the schema, merge
``--set`` overrides, then run the cross-key checks (``pipeline.infra.config.checks``).

Every problem raises ``ConfigError`` naming the file and the dotted key: an unknown key, a wrong
type, a value out of range, a string with a NUL byte, a file that is not UTF-8 TOML.
"""
from __future__ import annotations

import dataclasses
import math
import re
import typing
from pathlib import Path
from typing import Any

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from pipeline.infra.config.checks import cross_checks
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.learning import ModelsConfig
from pipeline.infra.config.own import Extendable, Key, Own, sections
from pipeline.infra.config.evaluation import ABLATION_KEYS
from pipeline.infra.config.root import PATH_KEYS, Config, project_root, to_dict
from pipeline.infra.filekind import not_regular
from pipeline.infra.nesting import depth

# Limits on what a config file may do, so a hostile or broken one is a named error, never a
# RecursionError: the shipped configs use one `extends` link and nest 3 tables deep.
MAX_EXTENDS = 16   # files in one `extends` chain (the file itself included)
MAX_NESTING = 16   # levels of tables and arrays in one file
MAX_CONFIG_BYTES = 1 << 20   # real configs are a few kB


def _check_scalar(value: Any, tp: Any, key: str, where: str) -> Any:
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: '{key}' must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: '{key}' must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: '{key}' must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where}: '{key}' must be finite, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: '{key}' must be a string, got {value!r}")
        if "\x00" in value:
            raise ConfigError(f"{where}: '{key}' contains a NUL byte")
        return value
    raise TypeError(f"unsupported config type {tp} for {key}")  # pragma: no cover


def _build(cls: type, table: dict, where: str, prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    kwargs: dict[str, Any] = {}
    if issubclass(cls, Extendable):   # the sections extensions declared under this one (config/own.py)
        own = sections(prefix[:-1], table, where)
        clash = sorted(set(own) & set(fields))
        if clash:
            raise ConfigError(f"{where}: an extension declares the section '{prefix}{clash[0]}', already a key of "
                              f"[{prefix[:-1]}]")
        kwargs["own"] = Own(prefix[:-1], {name: _own_key(sub, table, name, where, prefix) if isinstance(sub, Key) else
                                          _build(sub, _table(table.get(name, {}), where, prefix + name), where,
                                                 f"{prefix}{name}.") for name, sub in own.items()})
        fields = {**fields, **dict.fromkeys(own)}
        table = {k: v for k, v in table.items() if k not in own}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        allowed = ", ".join(sorted(fields))
        raise ConfigError(f"{where}: unknown key '{prefix}{unknown[0]}' (allowed here: {allowed})")
    for name, f in fields.items():
        if name not in table:
            continue
        key = prefix + name
        tp = hints[name]
        value = table[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, _table(value, where, key), where, key + ".")
            continue
        if typing.get_origin(tp) is tuple:
            inner = typing.get_args(tp)[0]
            words = f.metadata.get("words") or ()
            if isinstance(value, str) and words:
                if value not in words:
                    raise ConfigError(f"{where}: '{key}' = {value!r} must be a list or one of "
                                      f"{', '.join(map(repr, words))}")
                kwargs[name] = value
                continue
            if not isinstance(value, list):
                raise ConfigError(f"{where}: '{key}' must be a list, got {value!r}")
            items = tuple(_check_scalar(v, inner, f"{key}[{i}]", where) for i, v in enumerate(value))
            for i, v in enumerate(items):
                _check_range(v, f, f"{key}[{i}]", where)
            kwargs[name] = items
            continue
        value = _check_scalar(value, tp, key, where)
        _check_range(value, f, key, where)
        kwargs[name] = value
    return cls(**kwargs)


def _own_key(declared: Key, table: dict, name: str, where: str, prefix: str) -> Any:
    """An extension's key of the parent section (``own.Key``), checked like a built-in key."""
    if name not in table:
        return declared.default()
    value = _check_scalar(table[name], declared.type, prefix + name, where)
    _check_range(value, declared.field, prefix + name, where)
    return value


def _table(value: Any, where: str, key: str) -> dict:
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: '{key}' must be a table")
    return value


def _check_range(value: Any, f: dataclasses.Field, key: str, where: str) -> None:
    lo, hi, choices = f.metadata.get("lo"), f.metadata.get("hi"), f.metadata.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{where}: '{key}' = {value!r} is not one of {', '.join(map(repr, choices))}")
    if lo is not None and value < lo:
        raise ConfigError(f"{where}: '{key}' = {value!r} is below the minimum {lo}")
    if hi is not None and value > hi:
        raise ConfigError(f"{where}: '{key}' = {value!r} is above the maximum {hi}")


def ablation_config(cfg: Config, ablation: str) -> Config:
    """``cfg`` with one ``evaluate.ablations`` entry (``models.KEY=VALUE``) applied and validated."""
    key, raw = (t.strip() for t in ablation.split("=", 1))
    if key not in ABLATION_KEYS or not key.startswith("models."):
        raise ConfigError(f"evaluate.ablations: {ablation!r}: KEY must be one of {', '.join(ABLATION_KEYS)}"
                          " with its own model bank (models.*)")
    table = merge({"models": to_dict(cfg.models)}, parse_override(f"{key}={raw}"))
    where = f"{cfg.source_path or 'config'} (evaluate.ablations entry {ablation!r})"
    models = _build(ModelsConfig, table["models"], where, "models.")
    out = dataclasses.replace(cfg, models=models)
    cross_checks(out, where)
    return out


def load_config(path: str | Path, overrides: dict | None = None) -> Config:
    """Read, type-check and validate a TOML config.

    ``overrides`` is a nested dict merged over the file's tables (used by tests and ``--set``).
    """
    path = Path(path)
    where = str(path)
    table, set_in = _read_table(path)
    if overrides:
        if depth(overrides) > MAX_NESTING:
            raise ConfigError(f"--set: a value nests deeper than {MAX_NESTING} levels (MAX_NESTING)")
        table = merge(table, overrides)
        # a --set path counts as written in the file --config names
        set_in.update({k: path for k in PATH_KEYS if k.split(".")[1] in (overrides.get(k.split(".")[0]) or {})})
    try:
        cfg = _build(Config, table, where, "")
        roots = tuple((k, str(project_root(set_in[k]))) for k in PATH_KEYS if k in set_in)
        cfg = dataclasses.replace(cfg, source_path=str(path.resolve()), path_roots=roots)
        cross_checks(cfg, where)
    except ConfigError as e:
        if overrides and _file_alone_loads(path):  # the file is fine: the problem came from --set
            raise ConfigError(f"--set on the command line (over {where}){str(e)[len(where):]}") from None
        raise
    return cfg


def _file_alone_loads(path: Path) -> bool:
    try:
        load_config(path)
    except ConfigError:
        return False
    return True


def _read_toml(path: Path) -> dict:
    where = str(path)
    problem = not_regular(path, "config file")
    if problem is not None:   # /dev/zero, a FIFO, a folder: say what it is, never "not found"
        kind, what = problem
        raise ConfigError(f"{where}: config file not found" if kind == "missing" else
                          f"{where}: {what}; a config is a regular TOML file")
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as e:
        raise ConfigError(f"{where}: cannot read the config file ({e.strerror or e})") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{where}: more than {MAX_CONFIG_BYTES} bytes, too large for a config file "
                          "(real ones are a few kB); not parsed")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        hint = " (it looks like UTF-16)" if data[:2] in (b"\xff\xfe", b"\xfe\xff") else ""
        raise ConfigError(f"{where}: not UTF-8 text{hint}: byte {e.start} is {data[e.start:e.start + 1]!r}; "
                          "TOML files must be UTF-8") from None
    _check_key_depth(text, where)
    try:
        table = tomllib.loads(text.removeprefix("\ufeff"))
    except RecursionError:
        raise ConfigError(f"{where}: a value nests deeper than {MAX_NESTING} levels (MAX_NESTING)") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: not valid TOML: {e}") from None
    if depth(table) > MAX_NESTING:
        raise ConfigError(f"{where}: a value nests deeper than {MAX_NESTING} levels (MAX_NESTING)")
    return table


def _check_key_depth(text: str, where: str) -> None:
    """A dotted key (``a.b.c = 1`` or ``[a.b.c]``) deeper than MAX_NESTING, refused before parsing:
    tomllib's time and memory grow with the square of a dotted key's length."""
    deep = re.compile(r"\s*\[{0,2}\s*[\w-]+(?:\s*\.\s*[\w-]+){%d}" % MAX_NESTING)
    for n, line in enumerate(text.splitlines(), 1):
        if deep.match(line):
            raise ConfigError(f"{where}: line {n}: a key nests deeper than {MAX_NESTING} levels (MAX_NESTING)")


def _read_table(path: Path) -> tuple[dict, dict[str, Path]]:
    """The file's tables, and for each PATH_KEYS entry set the file that set it. A top-level
    ``extends = "other.toml"`` (relative to the file) first reads that config and merges this
    file's keys over it, so a preset states only what it changes; at most MAX_EXTENDS files."""
    chain: list[tuple[Path, dict]] = []
    while True:
        where = str(path)
        table = _read_toml(path)
        chain.append((path, table))
        base = table.pop("extends", None)
        if base is None:
            break
        if not isinstance(base, str) or not base:
            raise ConfigError(f"{where}: 'extends' must be a config file name, got {base!r}")
        parent = (path.parent / base).resolve()
        if parent in {p.resolve() for p, _ in chain}:
            raise ConfigError(f"{where}: 'extends' makes a cycle through {parent}")
        if not parent.is_file():
            raise ConfigError(f"{where}: 'extends' names {base!r}, not found at {parent}")
        if len(chain) >= MAX_EXTENDS:
            raise ConfigError(f"{chain[0][0]}: its 'extends' chain is longer than {MAX_EXTENDS} files "
                              f"(MAX_EXTENDS); {where} extends {base!r}")
        path = parent
    merged: dict = {}
    set_in: dict[str, Path] = {}
    for p, table in reversed(chain):   # the base first, each file's keys over it
        merged = merge(merged, table)
        for key in PATH_KEYS:
            section, name = key.split(".")
            if isinstance(table.get(section), dict) and name in table[section]:
                set_in[key] = p
    return merged, set_in


def merge(base: dict, over: dict) -> dict:
    """``over`` merged into ``base``, tables recursively (a new dict)."""
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


def parse_override(text: str) -> dict:
    """``a.b.c=VALUE`` (VALUE in TOML syntax) -> nested dict, for ``--set`` on the command line."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE")
    key, raw = text.split("=", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # bare words are strings
    out: dict = {}
    cur = out
    parts = key.strip().split(".")
    for p in parts[:-1]:
        cur = cur.setdefault(p, {})
    cur[parts[-1]] = value
    return out
