"""Errors and skip accounting shared by the dataset readers."""
from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

log = logging.getLogger("viewfuse.loaders")


class BadInputError(ValueError):
    """A dataset file is missing or malformed. The message starts with the file's path."""

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class SkipLog:
    """Counts and logs skipped items (a bad view out of 120), so a run can go on honestly."""

    def __init__(self, what: str = "item"):
        self.what = what
        self.count = 0
        self.reasons: Counter[str] = Counter()
        self.examples: list[str] = []

    def skip(self, err: BadInputError | str) -> None:
        self.count += 1
        msg = str(err)
        self.reasons[getattr(err, "problem", msg)] += 1
        if len(self.examples) < 20:
            self.examples.append(msg)
        log.warning("skipped %s: %s", self.what, msg)

    def summary(self) -> dict:
        return {"skipped": self.count, "reasons": dict(self.reasons), "examples": self.examples}

    def __str__(self) -> str:
        return f"{self.count} {self.what}(s) skipped" if self.count else f"no {self.what} skipped"
