"""What every config section is made of: the error naming file and key, and ``setting``, the
dataclass field whose metadata carries its range (``lo``/``hi``, also applied to every item of a list),
its choices and its doc, which ``pipeline.infra.config.load`` checks and ``viewfuse <stage> --help`` prints."""
from __future__ import annotations

import dataclasses
from dataclasses import field
from typing import Any

from pipeline.infra.errors import ConfigError  # noqa: F401 - its home: raised below the config package too

SEED_MAX = 2**32 - 1  # numpy, torch and Parquet metadata all take it


def setting(default: Any = dataclasses.MISSING, *, lo: float | None = None, hi: float | None = None,
       choices: tuple | None = None, factory: Any = None, doc: str = "", words: tuple = ()) -> Any:
    # ``words``: for a list-valued key, bare strings that stand for a rule instead of a list
    # (e.g. ``targets = "all"``); the field then holds that string.
    meta = {"lo": lo, "hi": hi, "choices": choices, "doc": doc, "words": words}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)
