"""Why a path is not a regular file to read, in words: the one check the dataset readers
(``loaders.files``) and the weights loader share. Only ``stat`` is called, never ``open``, so a
FIFO cannot block here and ``/dev/zero`` is never read."""
from __future__ import annotations

import os
import stat
from pathlib import Path

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def not_regular(path: str | Path, what: str = "file") -> tuple[str, str] | None:
    """None for a regular file (symlinks followed); else (kind, problem): kind ``"missing"``,
    ``"unreadable"`` or ``"not regular"``, and the problem in words naming ``what``."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "missing", f"{what} is missing" + (" (dangling symlink)" if os.path.islink(path) else "")
    except OSError as e:
        return "unreadable", f"cannot read {what} ({e.strerror or e})"
    if stat.S_ISREG(st.st_mode):
        return None
    kind = next((k for test, k in _KINDS if test(st.st_mode)), "not a regular file")
    via = f" (symlink to {os.path.realpath(path)})" if os.path.islink(path) else ""
    return "not regular", f"{what} is {kind}{via}, not a regular file; refused"
