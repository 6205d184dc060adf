"""The project installs its internal packages under the top-level names ``pipeline``, ``loaders``,
``reports`` and ``stages`` (the code imports them so). Another installed project with one of those
names would shadow them, or be shadowed, silently; importing ``viewfuse`` refuses that instead,
naming the module that is found and where this project's copy is."""
from __future__ import annotations

import importlib.util
from pathlib import Path

INTERNAL = ("pipeline", "loaders", "reports", "stages")
ROOT = Path(__file__).resolve().parents[1]


def collisions() -> list[str]:
    """One line per internal top-level name that does not resolve to this project's folder."""
    bad = []
    for name in INTERNAL:
        spec = importlib.util.find_spec(name)
        where = None if spec is None else (spec.origin or next(iter(spec.submodule_search_locations or []), None))
        if where is None or not Path(where).resolve().is_relative_to(ROOT / name):
            bad.append(f"'import {name}' finds {where or 'nothing'}, not viewfuse's {ROOT / name}")
    return bad


def check_install() -> None:
    bad = collisions()
    if bad:
        raise ImportError("viewfuse: another installed package takes one of viewfuse's internal top-level "
                          "names (install viewfuse in its own virtual environment; docs/api.md, "
                          "'Installing'):\n  " + "\n  ".join(bad))
