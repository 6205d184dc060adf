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

    LOG_FIRST = 10  # skips logged one by one; the rest are only counted (the manifest lists them)

    def skip(self, err: BadInputError | str) -> None:
        self.count += 1
        msg = str(err)
        self.reasons[getattr(err, "problem", msg)] += 1
        if len(self.examples) < 20:
            self.examples.append(msg)
        if self.count <= self.LOG_FIRST:
            log.warning("skipped %s: %s", self.what, msg)
        elif self.count == self.LOG_FIRST + 1:
            log.warning("skipped %s: %s (further skips of this kind are counted, not logged)", self.what, msg)

    def summary(self) -> dict:
        return {"skipped": self.count, "reasons": dict(self.reasons), "examples": self.examples}

    def __str__(self) -> str:
        return f"{self.count} {self.what}(s) skipped" if self.count else f"no {self.what} skipped"


class SkipPolicy:
    """``data.skip_bad_views`` for one stage run: with skips on, each dataset part gets a SkipLog
    (``log("avd")``) and the runner writes ``summary()`` into the stage manifest; with skips off,
    ``log`` returns None and the readers raise on the first bad entry."""

    def __init__(self, enabled: bool):
        self.enabled = bool(enabled)
        self.logs: dict[str, SkipLog] = {}

    @classmethod
    def from_config(cls, cfg) -> "SkipPolicy":
        return cls(cfg.data.skip_bad_views)

    def log(self, part: str, what: str | None = None) -> SkipLog | None:
        """The SkipLog of one dataset part (``"bigbird"``, ``"avd"``), or None when skips are off."""
        if not self.enabled:
            return None
        if part not in self.logs:
            self.logs[part] = SkipLog(what or f"{part} entry")
        return self.logs[part]

    def handle(self, err: BadInputError, part: str, what: str | None = None) -> None:
        """Skip ``err`` (counted under ``part``) or, with skips off, raise it."""
        sl = self.log(part, what)
        if sl is None:
            raise err
        sl.skip(err)

    @property
    def count(self) -> int:
        return sum(s.count for s in self.logs.values())

    def summary(self) -> dict:
        return {part: s.summary() for part, s in sorted(self.logs.items())}
