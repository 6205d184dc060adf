"""Progress for long loops: a tqdm bar on a terminal, a few plain log lines otherwise.

``bar(...)`` returns an object with tqdm's ``update``/``reset``/``close``/``set_postfix_str`` and
iteration, whatever the mode:

- ``auto`` (default): tqdm when stderr is a terminal; otherwise at most ``LOG_LINES`` plain
  lines per loop (at quarter marks, and only for loops that run at least ``LOG_AFTER_S`` seconds),
  so a redirected log holds no carriage returns or cursor codes.
- ``on``: tqdm even when redirected; ``off``: nothing.

``duration(seconds)`` writes a span of time for those lines. ``redirect_logging()`` wraps a run so log records and ``echo`` lines print above live bars
instead of being glued onto them (tqdm's ``logging_redirect_tqdm``).
"""
from __future__ import annotations

import contextlib
import logging
import sys
import time
from typing import Any, Iterable, Iterator

MODES = ("auto", "on", "off")
LOG_LINES = 5        # at most this many plain lines per loop in a log
LOG_AFTER_S = 5.0    # loops shorter than this print nothing in a log

_mode = "auto"
log = logging.getLogger("viewfuse.progress")


def set_mode(mode: str) -> None:
    global _mode
    if mode not in MODES:
        raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
    _mode = mode


def _use_tqdm() -> bool:
    if _mode == "on":
        return True
    if _mode == "off":
        return False
    stream = sys.stderr
    return bool(getattr(stream, "isatty", lambda: False)())


def bar(iterable: Iterable | None = None, *, total: int | None = None, desc: str = "",
        unit: str = "it", leave: bool = True, enabled: bool = True) -> Any:
    """A progress bar for one loop (see the module docstring); ``enabled=False`` gives a silent one."""
    if total is None and iterable is not None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    if enabled and _use_tqdm():
        from tqdm import tqdm
        return tqdm(iterable, total=total, desc=desc or None, unit=unit, leave=leave,
                    disable=False, dynamic_ncols=True)
    return LogBar(iterable, total=total, desc=desc, unit=unit,
                  lines=LOG_LINES if enabled and _mode != "off" else 0)


class LogBar:
    """The no-terminal stand-in: counts like tqdm, prints at most ``lines`` plain log lines."""

    def __init__(self, iterable: Iterable | None = None, *, total: int | None = None, desc: str = "",
                 unit: str = "it", lines: int = LOG_LINES):
        self.iterable, self.total, self.desc, self.unit = iterable, total, desc, unit
        self.lines = lines
        self.n = 0
        self.printed = 0
        self._t0 = time.perf_counter()
        self._next_mark = 1
        self._postfix = ""

    # tqdm-compatible surface --------------------------------------------------------------------
    def __iter__(self) -> Iterator:
        for x in self.iterable or ():
            yield x
            self.update(1)
        self.close()

    def __enter__(self) -> "LogBar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return int(self.total or 0)

    def update(self, n: int = 1) -> None:
        self.n += n
        if not self.total or self.printed >= self.lines - 1:
            return  # keep the last line for close()
        quarter = int(4 * self.n / self.total)
        if quarter >= self._next_mark and quarter < 4:
            self._next_mark = quarter + 1
            if time.perf_counter() - self._t0 >= LOG_AFTER_S:
                self._emit(f"{25 * quarter}%")

    def reset(self, total: int | None = None) -> None:
        self.total, self.n, self._next_mark = total, 0, 1

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self._postfix = s

    def set_description(self, desc: str = "", refresh: bool = True) -> None:
        self.desc = desc

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        if self.lines <= 0 or self.printed >= self.lines or self.n == 0:
            self.lines = 0
            return
        if self.printed or time.perf_counter() - self._t0 >= LOG_AFTER_S:
            self._emit("done")
        self.lines = 0  # a second close prints nothing

    def _emit(self, what: str) -> None:
        self.printed += 1
        of = f"/{self.total}" if self.total else ""
        extra = f", {self._postfix}" if self._postfix else ""
        log.info("%s: %s (%d%s %s, %.0f s%s)", self.desc or "progress", what, self.n, of, self.unit,
                 time.perf_counter() - self._t0, extra)


def duration(seconds: float, decimals: int = 0) -> str:
    """A span of seconds for a console line, in the one style of the stages' banners and the cost
    model's estimates: seconds below 2 min, minutes below 2 h, hours below 2 days, else days.
    (Numbers on report pages: ``reports.shared.numbers``, the floor above.)"""
    s, d = float(seconds), int(decimals)
    if s < 120:
        return f"{s:.{d}f} s"
    if s < 2 * 3600:
        return f"{s / 60:.{d}f} min"
    return f"{s / 3600:.1f} h" if s < 48 * 3600 else f"{s / 86400:.0f} days"


def echo(msg: str) -> None:
    """Print one line on stdout without breaking a live bar."""
    if _use_tqdm():
        from tqdm import tqdm
        tqdm.write(msg, file=sys.stdout)
        sys.stdout.flush()
    else:
        print(msg, flush=True)


@contextlib.contextmanager
def redirect_logging() -> Iterator[None]:
    """Log records print above live bars (only needed, and only active, when bars are drawn)."""
    if not _use_tqdm():
        yield
        return
    from tqdm.contrib.logging import logging_redirect_tqdm
    with logging_redirect_tqdm():
        yield
