"""Run every ``tests/bench/bench_*.py``: import it and call its ``main()``; then one summary: the
machine, each chain's split per stage (``bench_chains.py``) and the ratio of every route measured
against its previous one in the same run (the benches whose ``main()`` returns one).

    python tests/bench/run_all.py [--only gp,loto,features,chains]
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # the project root, for ``tests.*`` helpers


def summary(results: dict) -> list[str]:
    """The closing lines: the machine, the chains' table, and previous/current route ratios."""
    from tests.bench.bench_chains import machine, table

    lines = [f"== summary: {machine()}"]
    chains = results.get("bench_chains") or {}
    if chains:
        lines += table([(name, r["stages"], r) for name, r in chains.items()])
    for name, r in results.items():
        if isinstance(r, dict) and "previous_s" in r:
            u = r.get("unit", "s")
            cpu = (f"; CPU {r['previous_cpu_s']:.3g} -> {r['current_cpu_s']:.3g} {u}, "
                   f"{r['previous_cpu_s'] / max(r['current_cpu_s'], 1e-12):.1f}x" if "current_cpu_s" in r else "")
            lines.append(f"  {r['route']}: {r['previous_s']:.3g} -> {r['current_s']:.3g} {u} wall, "
                         f"{r['previous_s'] / max(r['current_s'], 1e-12):.1f}x{cpu}  ({name})")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="comma-separated bench names (bench_<name>.py), default all")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    only = {f"bench_{n.strip().removeprefix('bench_')}" for n in args.only.split(",") if n.strip()}
    paths = [p for p in sorted(HERE.glob("bench_*.py")) if not only or p.stem in only]
    if only - {p.stem for p in paths}:
        raise SystemExit(f"--only: no tests/bench/{', '.join(sorted(only - {p.stem for p in paths}))}.py")
    results = {}
    for path in paths:
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        print(f"== {path.name}", flush=True)
        t0 = time.perf_counter()
        results[path.stem] = mod.main()
        print(f"== {path.name} done in {time.perf_counter() - t0:.1f} s\n", flush=True)
    print("\n".join(summary(results)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
