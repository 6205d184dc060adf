"""Print the uv flags that make ``uv pip install`` resolve as this machine's pip would.

uv does not read pip's configuration (pip.conf files, PIP_* variables), so the Makefile passes
pip's index URL, extra index URLs, find-links and constraint files on, plus pip's resolution rule
(the best version across all indexes, where uv's default takes the first index that has a
package). Run with the venv's python: ``python tools/uv_flags.py``. Prints nothing extra when pip
has no configuration.
"""
from __future__ import annotations

import shlex
import subprocess
import sys

# pip option (as in `pip config list`) -> uv flag; values are whitespace-separated lists
FLAGS = {"index-url": "--index-url", "extra-index-url": "--extra-index-url",
         "find-links": "--find-links", "constraint": "--constraint"}


def pip_config() -> dict[str, list[str]]:
    """Effective pip settings for ``install``, later sources winning as in pip (files, then env)."""
    try:
        out = subprocess.run([sys.executable, "-m", "pip", "config", "list"], capture_output=True,
                             text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return {}
    rank = {"global": 0, "install": 1, ":env:": 2}   # pip: the install section over global, env over files
    found: dict[str, tuple[int, list[str]]] = {}
    for line in out.splitlines():
        key, sep, value = line.partition("=")
        section, _, name = key.rpartition(".")
        if sep and name in FLAGS and section in rank and rank[section] >= found.get(name, (-1,))[0]:
            words = shlex.split(value)
            found[name] = (rank[section], words[0].split() if words else [])
    return {name: values for name, (_, values) in found.items()}


def main() -> None:
    args = ["--index-strategy", "unsafe-best-match"]
    for name, values in pip_config().items():
        for v in values:
            args += [FLAGS[name], v]
    print(shlex.join(args))


if __name__ == "__main__":
    main()
