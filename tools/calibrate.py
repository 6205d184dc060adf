"""`make calibrate`: the whole calibration suite (pipeline.evaluation.calibration), its table written
into docs/calibration.md between the markers (one current table). Usage:
    python tools/calibrate.py [--replications 1000] [--seed 0] [--out docs/calibration.md] [--candidates ...]"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path

from pipeline.evaluation.calibration import suite as S
from pipeline.evaluation.calibration.table import markdown

BEGIN, END = "<!-- calibration table: begin (tools/calibrate.py) -->", "<!-- calibration table: end -->"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replications", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bootstrap", type=int, default=2000, help="draws of the bootstrap candidate (evaluate.bootstrap)")
    ap.add_argument("--candidates", nargs="+", default=list(S.CANDIDATES), choices=list(S.CANDIDATES))
    ap.add_argument("--out", default="docs/calibration.md")
    ap.add_argument("--json", default=None, help="also write the rows as JSON here")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = S.suite(R=a.replications, seed=a.seed, candidates=a.candidates, n_boot=a.bootstrap)
    secs = time.perf_counter() - t0
    R = a.replications
    mc = 100 * 1.96 * math.sqrt(0.95 * 0.05 / R)
    cands = "" if list(a.candidates) == list(S.CANDIDATES) else " --candidates " + " ".join(f"'{c}'" for c in a.candidates)
    text = (f"{BEGIN}\n{R} replications a design and regime (seed {a.seed}, bootstrap {a.bootstrap} draws), "
            f"{secs:.0f} s: `python tools/calibrate.py --replications {R} --seed {a.seed}{cands}`. Every share in % with its "
            f"Wilson 95 % interval over the replications: the Monte Carlo error of a 95 % coverage is ±{mc:.1f} "
            f"points (1.96 sqrt(0.95 × 0.05 / {R})).\n\n{markdown(rows)}{END}")
    out = Path(a.out)
    doc = out.read_text() if out.exists() else ""
    if BEGIN in doc and END in doc:
        doc = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: text, doc, flags=re.S)
    else:
        doc = doc + ("\n" if doc else "") + text + "\n"
    out.write_text(doc)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=float))
    print(markdown(rows))
    print(f"{secs:.0f} s; table written to {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
