"""The simulate stage at the default config, with its small regime sweep.

Printed: wall time (goal: under 2 minutes on the 2-core machine, ``make simulate``) and its split:
GP fits, the two scenarios at full size, the sweep, the rerun of the sweep's best point, the report;
and how many of the paper's claims hold.

    python tests/bench/bench_simulate.py [--config FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "synthetic.toml"))
    args = ap.parse_args(argv or [])
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure

    cfg = load_config(args.config)
    t0 = time.perf_counter()
    ensure(cfg, "simulate", force=True)
    took = time.perf_counter() - t0
    summary = json.loads((cfg.stage_dir("simulate") / "summary.json").read_text())
    tim = summary["timings_s"]
    claims = summary.get("claims") or []
    g = (summary.get("sweep") or {}).get("grid") or {}
    print(f"simulate stage: {took:.1f} s wall (goal < 120 s); sweep {g.get('name', 'off')} "
          f"{len(g.get('noise', []))} x {len(g.get('sigma_max', []))} points x {g.get('realizations', 0)} realizations")
    print("  " + ", ".join(f"{k} {v:.1f} s" for k, v in tim.items()))
    print(f"  paper claims holding: {sum(c['holds'] for c in claims)} of {len(claims)}")


if __name__ == "__main__":
    main(sys.argv[1:])
