"""docs/api.md's table lists every public name: each of ``viewfuse.__all__`` appears there (a name
exported but not documented is one a newcomer cannot find)."""
from __future__ import annotations

import re

import viewfuse as vf
from tests.conftest import ROOT


def documented(name: str, table: str) -> bool:
    return bool(re.search(rf"`{re.escape(name)}[`(]", table)) or (name.startswith("unregister_")
                                                                   and "`unregister_*`" in table)


def test_every_exported_name_is_in_the_api_table():
    table = "\n".join(line for line in (ROOT / "docs" / "api.md").read_text().splitlines() if line.startswith("| `"))
    assert documented("setting", table) and not documented("setting_label", table)
    assert [n for n in vf.__all__ if not documented(n, table)] == []
