"""Memory budget: peak summed RSS (process tree, ``tools/peak_rss.py``) or refusal time
of the settings whose memory grows, after the budget; docs/benchmarks.md "Memory budget" quotes it.

Cases that refuse run under ``run.memory_gb = 6`` (the audit's watchdog); the MC-dropout case
scores 8 crops with N_s = 1000 directly (the whole features stage at N_s = 1000 is hours of CPU),
once in passes of ``HEAD_ROWS`` rows and once in one pass (the code before the budget).
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
CLI = [PY, "-m", "stages.commands.cli"]

MC = """
import sys, torch
from pipeline.scoring import mc_dropout
from pipeline.scoring.alexnet import build_alexnet, init_for_training
if sys.argv[1] == 'one-pass':
    mc_dropout.HEAD_ROWS = 10**9
torch.set_num_threads(2)
sc = mc_dropout.MCDropoutScorer(init_for_training(build_alexnet(12, 0.5), 0).eval())
n = int(sys.argv[2]) if len(sys.argv) > 2 else 8
x = torch.randn(n, 3, 112, 112)
sc.score(x, [mc_dropout.crop_seed(0, str(i)) for i in range(n)], n_samples=1000)
"""


def cases(art: str) -> list[tuple[str, list[str]]]:
    s = ["--progress", "off", "--set", f"run.artifacts={art}"]
    return [
        ("classifier.training.train_images=10000000", CLI + ["classifier", *s, "--set", "classifier.training.train_images=10000000"]),
        ("simulate.chunk=100000 realizations=100000, memory_gb=6",
         CLI + ["simulate", *s, "--set", "run.memory_gb=6", "--set", "simulate.chunk=100000",
                "--set", "simulate.realizations=100000"]),
        ("simulate.chunk=100000 realizations=1000 sweep=off",
         CLI + ["simulate", *s, "--set", "simulate.chunk=100000", "--set", "simulate.realizations=1000",
                "--set", "simulate.sweep=off", "--set", "run.name=sim1000"]),
        ("MC dropout 8 crops x N_s=1000, passes of HEAD_ROWS", [PY, "-c", MC, "passes"]),
        ("MC dropout 8 crops x N_s=1000, one pass (before)", [PY, "-c", MC, "one-pass"]),
    ]


def main() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as art:
        for name, cmd in cases(art):
            r = subprocess.run([PY, str(ROOT / "tools" / "peak_rss.py"), "--", *cmd], cwd=ROOT, env=env,
                               capture_output=True, text=True)
            print(f"{name}: {r.stderr.strip().splitlines()[-1]}", flush=True)


if __name__ == "__main__":
    main()
