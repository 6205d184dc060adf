"""Where the tests find the real data: ``../shared/realdata`` beside the project root (CI's
layout), or the folder ``VIEWFUSE_REALDATA`` names (a git worktree, a user's own download). Tests
that need it skip, saying so and where to get it, when it is absent."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REALDATA = Path(os.environ.get("VIEWFUSE_REALDATA") or ROOT.parent / "shared" / "realdata")


def need(part: str) -> Path:
    """``REALDATA / part``, or skip the test with a message naming what is missing."""
    path = REALDATA / part
    if not path.exists():
        pytest.skip(f"real data {path} is absent: put the project's realdata folder at ../shared/realdata beside "
                    "the project root or set VIEWFUSE_REALDATA to it (README: where each dataset comes from)")
    return path
