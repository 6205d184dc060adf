"""Which checkout's code runs. A project copied with ``cp -a`` keeps a venv whose editable install
imports the original's modules: run from the copy, ``viewfuse`` would run (and call stages up to
date against) the other checkout's code. The Makefile rebuilds such a venv; this says so when the
CLI is started by hand from inside one checkout while its code comes from another. A checkout
that is imported first (``PYTHONPATH`` pointing at it, as in a git worktree beside the main one)
is the one that runs, and nothing is said."""
from __future__ import annotations

import os
from pathlib import Path

from stages.framework.registry import ROOT

MARKERS = ("pyproject.toml", "stages", "pipeline")  # what makes a folder a viewfuse checkout


def checkout_of(folder: str | Path) -> Path | None:
    """The viewfuse checkout ``folder`` lies in (its nearest parent holding a viewfuse
    pyproject.toml, ``stages/`` and ``pipeline/``), or None."""
    p = Path(os.path.realpath(folder))
    for d in (p, *p.parents):
        if all((d / m).exists() for m in MARKERS):
            try:
                head = (d / "pyproject.toml").read_text(errors="replace")[:4000]
            except OSError:
                return None
            return d if 'name = "viewfuse"' in head else None
    return None


def other_checkout(cwd: str | Path | None = None) -> str | None:
    """A warning when the working folder is inside a viewfuse checkout other than the one whose
    code is imported (``ROOT``), else None."""
    here = checkout_of(os.getcwd() if cwd is None else cwd)
    if here is None or here == Path(os.path.realpath(ROOT)):
        return None
    return (f"the code that runs is {ROOT}'s, not that of the checkout you are in ({here}): its venv or "
            f"editable install points at the other one (a copied project?). Run 'make' in {here} to rebuild "
            f"its .venv, or put {here} first on PYTHONPATH")
