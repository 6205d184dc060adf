"""Speed goal of ``viewfuse status``: under 1 s warm and under 2 s cold (docs/design.md).

- warm: the median of three runs after one warm-up run (byte code cached, files in the page cache).
- cold: byte code compiled from source (an empty ``PYTHONPYCACHEPREFIX``) and the project's and the
  interpreter's library files dropped from the page cache where the kernel allows it
  (``posix_fadvise(DONTNEED)``; pages other processes keep mapped stay).

Each run is a new process on an empty artifacts folder (every stage's key is still computed).
Prints measured values and their ratios to the goals (ratio < 1 = goal met).
"""
from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GOAL_WARM_S, GOAL_COLD_S = 1.0, 2.0


def _drop_page_cache(*roots: Path) -> int:
    n = 0
    for root in roots:
        for dirpath, _, names in os.walk(root):
            for name in names:
                try:
                    fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
                except OSError:
                    continue
                try:
                    os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
                    n += 1
                finally:
                    os.close(fd)
    return n


def _status(artifacts: str, env: dict) -> tuple[float, float]:
    """(wall, CPU) seconds of one ``viewfuse status``; CPU time is what a loaded machine does not inflate."""
    r0, t = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run([sys.executable, "-m", "stages.commands.cli", "status", "--set", f"run.artifacts={artifacts}"],
                   cwd=ROOT, env=env, check=True, capture_output=True)
    wall, r1 = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as art, tempfile.TemporaryDirectory() as pyc:
        _status(art, env)
        runs = [_status(art, env) for _ in range(3)]
        warm, warm_cpu = statistics.median(w for w, _ in runs), statistics.median(c for _, c in runs)
        _drop_page_cache(ROOT / "pipeline", ROOT / "stages", ROOT / "loaders", ROOT / "reports",
                         Path(sysconfig.get_paths()["purelib"]), Path(sysconfig.get_paths()["stdlib"]))
        cold, cold_cpu = _status(art, {**env, "PYTHONPYCACHEPREFIX": pyc})
    print(f"status warm {warm:.2f} s wall, {warm_cpu:.2f} s CPU (goal {GOAL_WARM_S} s, ratio {warm / GOAL_WARM_S:.2f}); "
          f"cold {cold:.2f} s wall, {cold_cpu:.2f} s CPU (goal {GOAL_COLD_S} s, ratio {cold / GOAL_COLD_S:.2f})")


if __name__ == "__main__":
    main()
