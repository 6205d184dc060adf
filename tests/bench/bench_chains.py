"""Each chain's split per stage (data, classifier, features, models, evaluate, report), with the
machine and its load: the main job (configs/synthetic.toml) from an empty run folder, and the real
chains where they are asked for and their data is present.

Every chain runs ``viewfuse evaluate`` (as ``make features models evaluate``: the whole upstream, and
the report after it) once in a temporary
artifacts folder under ``/usr/bin/time -v``: the per-stage wall seconds and CPU seconds come from
each stage's manifest (``seconds``, ``cpu_seconds``: this process and its reaped workers), the
chain's wall, user + system CPU and peak RSS from ``time``. The load average is printed before and
after: on a shared machine the CPU seconds are the numbers to compare.

    python tests/bench/bench_chains.py                                   # the main job
    python tests/bench/bench_chains.py --config configs/real.toml --config configs/real_full.toml
    python tests/bench/bench_chains.py --run artifacts/real_full         # a finished run's split
``VIEWFUSE_BENCH_CHAINS="configs/real.toml configs/real_category.toml" make bench`` adds real chains.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

STAGE_RE = re.compile(r"^\[(\w+)\] done in ([0-9.]+) (s|min)")
STAGES = ("data", "classifier", "features", "models", "evaluate", "report")
MAIN_JOB_GOAL_S, REAL_GOAL_S = 300.0, 600.0


def machine() -> str:
    """CPU model, cores and the 1-minute load average, one line."""
    from pipeline.infra.fingerprint import cpu_model

    return f"{cpu_model()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}"


def _time_v(text: str, field: str) -> float:
    m = re.search(rf"{re.escape(field)}: ([0-9.:]+)", text)
    return float(m.group(1)) if m else float("nan")


def run_chain(config: Path, artifacts: Path) -> dict:
    """``viewfuse evaluate`` (data .. evaluate, then report) on ``config`` into ``artifacts``: each
    stage's seconds (its "done in" line), the chain's wall, CPU and peak RSS (GB)."""
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "stages.commands.cli", "evaluate", "--config", str(config),
           "--progress", "off", "--set", f"run.artifacts={artifacts}"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    p = subprocess.run(cmd, check=False, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode:
        raise RuntimeError(f"{config.name} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    text = p.stdout + p.stderr
    stages = {m.group(1): float(m.group(2)) * (60 if m.group(3) == "min" else 1)
              for m in map(STAGE_RE.match, text.splitlines()) if m}
    return {"stages": stages, "wall_s": wall, "cpu_s": _time_v(p.stderr, "User time (seconds)") + _time_v(p.stderr, "System time (seconds)"),
            "peak_gb": _time_v(p.stderr, "Maximum resident set size (kbytes)") / 2**20}


def stage_split(run_dir: Path) -> dict[str, tuple[float, float]]:
    """{stage: (wall s, CPU s)} from the finished stages' manifests (nan where not recorded)."""
    out = {}
    for st in STAGES:
        m = run_dir / st / "manifest.json"
        if m.is_file():
            man = json.loads(m.read_text())
            out[st] = (float(man.get("seconds", "nan")), float(man.get("cpu_seconds", "nan")))
    return out


def _cell(wall_cpu: tuple[float, float] | None) -> str:
    if wall_cpu is None:
        return f"{'-':>17}"
    wall, cpu = wall_cpu
    return f"{wall:8.1f} ({cpu:5.0f})" if cpu == cpu else f"{wall:8.1f}        "  # nan: not recorded


def table(rows: list[tuple[str, dict, dict | None]]) -> list[str]:
    """One line per chain: each stage's wall (CPU) seconds, the chain's wall, CPU and peak RSS."""
    head = f"  {'chain':<22}" + "".join(f"{s:>17}" for s in STAGES) + f"{'chain wall':>12}{'CPU s':>8}{'peak GB':>9}"
    lines = [head, "  " + "-" * (len(head) - 2)]
    for name, split, chain in rows:
        cells = "".join(_cell(split.get(s)) for s in STAGES)
        tail = (f"{chain['wall_s']:12.1f}{chain['cpu_s']:8.0f}{chain['peak_gb']:9.2f}" if chain else "")
        lines.append(f"  {name:<22}{cells}{tail}")
    lines.append("  (stage cells: wall seconds (CPU seconds); a stage that did not run shows -)")
    return lines


def estimate_lines(cfg, split: dict[str, tuple[float, float]]) -> list[str]:
    """Each stage's cost estimate (pipeline/infra/cost.py) against what it took here, and whether it
    lies within a factor of two (tests/support/estimates.py). A machine-dependent check, so it lives
    here: the estimates stand for the reference machine, and a faster one runs a small stage in
    under half the estimate (a 1.4 s models stage against 3.5 s on CI's machine)."""
    from pipeline.infra.cost import estimate
    from pipeline.infra.device import available_cores
    from tests.support.estimates import misfit

    out, cores = [], available_cores()
    for st, (wall, cpu) in split.items():
        est = estimate(cfg, st).seconds
        problem = misfit(st, est, wall, cpu, cores) if cpu == cpu else None
        out.append(f"    {st:<10} estimate {est:8.1f} s, took {wall:8.1f} s wall ({cpu:6.1f} CPU s): "
                   f"{problem or 'within a factor of two'}")
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", action="append", default=[], help="a chain to run (repeatable); default: the main job")
    ap.add_argument("--run", action="append", default=[], help="print a finished run folder's split, run nothing")
    args, _ = ap.parse_known_args([] if argv is None else argv)
    print(f"machine: {machine()}")
    if args.run:
        print("\n".join(table([(Path(r).name, stage_split(Path(r)), None) for r in args.run])))
        return {}
    configs = args.config or ["configs/synthetic.toml", *os.environ.get("VIEWFUSE_BENCH_CHAINS", "").split()]
    real = Path(os.environ.get("VIEWFUSE_REALDATA") or ROOT.parent / "shared" / "realdata")
    from pipeline.infra.config import load_config

    rows, results = [], {}
    for c in configs:
        path = (ROOT / c).resolve()
        if path.name.startswith("real") and not real.is_dir():
            print(f"  {path.name}: skipped, real data {real} is absent")
            continue
        name = load_config(path).run.name
        load0 = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as tmp:
            chain = run_chain(path, Path(tmp))
            split = stage_split(Path(tmp) / name)  # (wall, CPU) from the manifests
        goal = MAIN_JOB_GOAL_S if path.name == "synthetic.toml" else REAL_GOAL_S
        print(f"  {path.name}: {chain['wall_s']:.0f} s wall (goal {goal:.0f} s: ratio {chain['wall_s'] / goal:.2f}), "
              f"{chain['cpu_s']:.0f} CPU s, peak RSS {chain['peak_gb']:.2f} GB; load average {load0:.1f} before, "
              f"{os.getloadavg()[0]:.1f} after", flush=True)
        for line in estimate_lines(load_config(path), split):
            print(line)
        rows.append((path.name, split, chain))
        results[path.name] = {**chain, "stages": split}
    if rows:
        print("\n".join(table(rows)))
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
