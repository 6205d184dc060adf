"""Nesting depth of a parsed JSON/TOML value, measured without recursion, so a file nested
100,000 deep is refused by its readers with a named error instead of a RecursionError."""
from __future__ import annotations

from typing import Any


def depth(value: Any) -> int:
    """Levels of dicts/lists/tuples in ``value`` (a scalar is 0), iteratively."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        if isinstance(v, (list, tuple)):
            deepest = max(deepest, d + 1)
            stack += [(x, d + 1) for x in v if isinstance(x, (dict, list, tuple))]
    return deepest
