"""Run a command and print its wall time and the peak summed RSS of its process tree (workers
included, which ``/usr/bin/time -v`` misses), sampled every 50 ms. The memory-budget table in
docs/benchmarks.md comes from it: ``python tools/peak_rss.py -- viewfuse data --set ...``."""
from __future__ import annotations

import subprocess
import sys
import time

import psutil


def main(argv: list[str]) -> int:
    cmd = argv[argv.index("--") + 1:] if "--" in argv else argv
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd)
    root, peak = psutil.Process(proc.pid), 0
    while proc.poll() is None:
        total = 0
        try:
            for p in [root, *root.children(recursive=True)]:
                try:
                    total += p.memory_info().rss
                except psutil.Error:
                    pass
        except psutil.Error:
            pass
        peak = max(peak, total)
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    print(f"peak_rss_gib={peak / 2**30:.2f} wall_s={wall:.1f} rc={proc.returncode}", file=sys.stderr)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
