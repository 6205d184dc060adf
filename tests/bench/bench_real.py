"""Speed goal of the real-imagery chain: ``make features models evaluate CONFIG=configs/real.toml``
(data and classifier included, from an empty run folder) in <= 600 s with peak RSS <= 4 GB on
this machine.

Runs the CLI once under ``/usr/bin/time -v`` into a temporary artifacts folder and prints each
stage's seconds (its "done in" line), the total wall time, the peak RSS of the largest process and
the ratios to the goals (ratio < 1 = goal met), with the load average before and after (the
machine may be shared: a loaded machine's seconds say so), then the split inside the stages from
their manifests (features: training views / AVD crops; evaluate: its ``timings_s``, the cells per
method included). Skips where ../shared/realdata is absent.

``VIEWFUSE_BENCH_REAL_CONFIG=configs/real_full.toml`` benches another config;
``python tests/bench/bench_real.py --run artifacts/real_full`` prints the split of a finished run
folder without running anything.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_chains import run_chain  # noqa: E402  (also when run alone)

ROOT = Path(__file__).resolve().parents[2]
GOAL_S, GOAL_GB = 600.0, 4.0


def split(run_dir: Path) -> list[str]:
    """Lines of each finished stage's seconds and the split its manifest records."""
    out = []
    for st in ("data", "classifier", "features", "models", "evaluate", "report"):
        m = run_dir / st / "manifest.json"
        if not m.is_file():
            out.append(f"  {st:<11} (not finished)")
            continue
        man = json.loads(m.read_text())
        extra = man.get("extra") or {}
        out.append(f"  {st:<11} {float(man.get('seconds', float('nan'))):7.1f} s")
        inner = extra.get("timings") or extra.get("timings_s") or {}
        for k, v in sorted(inner.items(), key=lambda kv: -float(kv[1] or 0)):
            out.append(f"      {k:<44} {float(v):8.1f} s")
        if st == "evaluate" and extra.get("n_cells"):
            out.append(f"      {'cells':<44} {extra['n_cells']:8d}")
    return out


def main() -> None:
    if "--run" in sys.argv:
        run_dir = Path(sys.argv[sys.argv.index("--run") + 1])
        print("\n".join([f"split of {run_dir}:"] + split(run_dir)))
        return
    real = Path(os.environ.get("VIEWFUSE_REALDATA") or ROOT.parent / "shared" / "realdata")
    if not (real / "coil100").is_dir() or not (real / "avd").is_dir():
        print(f"skipped: real data {real} is absent (README, Real photographs)")
        return
    if not Path("/usr/bin/time").is_file():
        print("skipped: /usr/bin/time (GNU time) is not installed")
        return
    config = ROOT / os.environ.get("VIEWFUSE_BENCH_REAL_CONFIG", "configs/real.toml")
    from pipeline.infra.config import load_config

    name = load_config(config).run.name
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        r = run_chain(config, Path(tmp))
        inner = split(Path(tmp) / name)
    load1 = os.getloadavg()
    for st, sec in r["stages"].items():
        print(f"  {st:<11} {sec:7.1f} s")
    print(f"  chain wall  {r['wall_s']:7.1f} s (goal {GOAL_S:.0f} s: ratio {r['wall_s'] / GOAL_S:.2f}); peak RSS "
          f"{r['peak_gb']:.2f} GB (goal {GOAL_GB:.0f} GB: ratio {r['peak_gb'] / GOAL_GB:.2f}); {os.cpu_count()} cores, "
          f"load average {load0[0]:.1f} before, {load1[0]:.1f} after")
    print("\n".join([f"  split ({config.name}):"] + inner))


if __name__ == "__main__":
    main()
