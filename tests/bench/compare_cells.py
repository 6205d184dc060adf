"""Every cell of a finished default run (its models and features), through the engine and the
reference engine (tests/support/reference_fusion.py), interleaved cell by cell in one process: the largest
relative log-posterior difference and both times (wall and CPU). Reads the run, writes nothing.

    python tests/bench/compare_cells.py [ARTIFACTS_ROOT]   # default: the project's artifacts/
"""
import json, sys, time
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from pipeline.infra.config import load_config
from pipeline.infra.outputs import name as out_name
from pipeline.scoring.features import read_features
from stages import evaluate as SE
from pipeline.evaluation.grid import population as P, experiments as E
import pipeline.method.fusion as Fu
from pipeline.method import engine
from tests.support import reference_fusion as R
over = {"run": {"artifacts": sys.argv[1]}} if len(sys.argv) > 1 else None
cfg = load_config(Path(__file__).resolve().parents[2] / "configs" / "synthetic.toml", over)
root = cfg.run_dir
banks, indexes = SE.load_banks(root / "models", ())
avd, scores, meta = read_features(root / "features" / out_name("features", "avd"))
scans = sorted(avd["scan"].unique())
from stages.framework.runner import SkipPolicy
intr, steps, grids, _ = SE.scan_geometry(cfg, scans, avd, SkipPolicy(True))
truth = json.loads((root / "data" / "truth.json").read_text())
cells, tracks, skipped = P.build_cells(cfg.evaluate, avd, scores, indexes, truth, intr, steps, None, grids)
bank = banks["default"]
ps = engine.plan(bank).routes()
print(len(cells), "cells;", bank, "routes", {k: v for k, v in ps.items() if k != "P"}, "P percentiles", np.percentile(ps["P"], [0, 25, 50, 75, 100]))
print("length scales", np.percentile(bank.length_scale, [0, 10, 25, 50, 75, 90, 100]).round(3))
def patch(ref):
    for mod in (Fu, E):
        mod.fuse_with_uncertainty = R.fuse_with_uncertainty if ref else NEW[0]
        mod.fuse_model_based = R.fuse_model_based if ref else NEW[1]
NEW = (Fu.fuse_with_uncertainty, Fu.fuse_model_based)
tn = tr = 0.0; cn = cr = 0.0; worst = 0.0
for i, cell in enumerate(cells):
    patch(False); t0, c0 = time.perf_counter(), time.process_time(); a = P.run_cell(banks, cell); tn += time.perf_counter() - t0; cn += time.process_time() - c0
    patch(True); t0, c0 = time.perf_counter(), time.process_time(); b = P.run_cell(banks, cell); tr += time.perf_counter() - t0; cr += time.process_time() - c0
    for key in a["posts"]:
        for m in a["posts"][key]:
            x, y = a["posts"][key][m], b["posts"][key][m]
            worst = max(worst, float(np.max(np.abs(x - y) / np.maximum(1, np.abs(y)))))
print(f"new {tn:.1f} s wall {cn:.1f} s CPU; reference {tr:.1f} s wall {cr:.1f} s CPU; ratio {tr/tn:.2f}x wall {cr/cn:.2f}x CPU; worst relative log-posterior difference {worst:.1e}")
