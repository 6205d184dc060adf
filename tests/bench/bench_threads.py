"""Torch work beside a CPU hog: CPU seconds under load against idle, and wall time
against the share of the machine the work gets (printed, never asserted; goal: CPU s under a hog
within 1.3x of idle).

Two workloads, each in a fresh process per (route, condition), so the OpenMP runtime reads its
environment anew:
  features: a slice of the features stage of configs/real.toml — AlexNet at 112 px, batches of
            16 crops, the deterministic pass + 10 MC-dropout samples each (``score_batch``, the
            stage's task), ``--batches`` batches (the full stage scores ~1,700 batches; a slice
            keeps the 3 x 2 runs short, and the per-batch cost is what the ratios compare);
  classifier: ``--images`` images of one classifier epoch (``train_classifier``, batch 64,
            112 px; the full epoch is 6,400 images).
Conditions: idle (nothing of ours beside it), and beside one busy loop per core at nice 0 and at
nice 19. Routes: previous (libgomp's default spin-wait, threads fixed at the cores) and current
(``pipeline.infra.threads``: no spinning, threads re-chosen each second from the free cores).
"Idle" is only as idle as the machine is: the line says the load average before each run.

    python tests/bench/bench_threads.py [--batches 24] [--images 640] [--only features,classifier]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

GOAL = 1.3


def _features(batches: int) -> None:
    import numpy as np

    import torch

    from pipeline.infra.threads import pace
    from pipeline.scoring.alexnet import build_alexnet, init_for_training
    from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed

    model = init_for_training(build_alexnet(12, 0.5), 0).eval()
    sc = MCDropoutScorer(model, "cpu")
    rng = np.random.default_rng(0)
    x = torch.from_numpy(rng.standard_normal((16, 3, 112, 112)).astype(np.float32))
    seeds = [crop_seed(0, f"c{i}") for i in range(16)]
    for _ in range(batches):
        pace()   # as score_batch does
        sc.score(x, seeds, 10)


def _classifier(images: int) -> None:
    import numpy as np

    from pipeline.scoring.alexnet import build_alexnet, init_for_training
    from pipeline.scoring.training import train_classifier

    rng = np.random.default_rng(0)
    xs = rng.integers(0, 256, (images, 112, 112, 3), dtype=np.uint8)
    ys = rng.integers(0, 12, images).astype(np.int64)
    model = init_for_training(build_alexnet(12, 0.5), 0)
    train_classifier(model, xs, ys, epochs=1, batch_size=64, lr=1e-4, weight_decay=0.0, warmup_steps=2,
                     seed=0, mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25), precision="fp32", progress=False)


def child(work: str, route: str, n: int) -> None:
    """One measured run, in this process: prints a JSON line."""
    if route == "previous":
        import torch  # noqa: F401  (libgomp loads with the environment as it is: spin-wait)
    import pipeline  # noqa: F401  (current: sets the passive wait before torch loads)
    import contextlib

    import torch

    from pipeline.infra.device import available_cores
    from pipeline.infra.threads import torch_following

    cores = available_cores()
    torch.set_num_threads(cores)
    follow = torch_following(cores) if route == "current" else contextlib.nullcontext()
    t0, c0 = time.perf_counter(), time.process_time()
    with follow as watch:
        (_features if work == "features" else _classifier)(n)
    print(json.dumps({"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0,
                      "threads": getattr(watch, "counts", {cores: 0})}), flush=True)


def _hogs(nice: int | None) -> list[subprocess.Popen]:
    if nice is None:
        return []
    return [subprocess.Popen(["nice", "-n", str(nice), sys.executable, "-c", "while True: pass"])
            for _ in range(os.cpu_count() or 1)]


def measure(work: str, route: str, nice: int | None, n: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "KMP_BLOCKTIME", "OMP_WAIT_POLICY")}
    env["PYTHONPATH"] = str(ROOT)
    load = os.getloadavg()[0]
    hogs = _hogs(nice)
    try:
        time.sleep(0.5 if hogs else 0)
        out = subprocess.run([sys.executable, __file__, "--child", work, route, str(n)], env=env,
                             capture_output=True, text=True, check=True).stdout
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    return {**json.loads(out.strip().splitlines()[-1]), "load": load}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, default=24)
    ap.add_argument("--images", type=int, default=640)
    ap.add_argument("--only", default="features,classifier")
    ap.add_argument("--routes", default="previous,current")
    ap.add_argument("--child", nargs=3, metavar=("WORK", "ROUTE", "N"))
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]))
        return {}
    from tests.bench.bench_chains import machine

    cores = os.cpu_count() or 1
    print(f"bench_threads: {machine()}; conditions: idle (the machine as it is), {cores} busy loop(s) at "
          "nice 0, at nice 19")
    res: dict = {}
    for work in [w.strip() for w in args.only.split(",") if w.strip()]:
        n = args.batches if work == "features" else args.images
        for route in [r.strip() for r in args.routes.split(",") if r.strip()]:
            runs = {c: measure(work, route, nice, n) for c, nice in (("idle", None), ("nice 0", 0), ("nice 19", 19))}
            res[(work, route)] = runs
            idle = runs["idle"]
            for c, r in runs.items():
                share = r["cpu"] / max(r["wall"] * cores, 1e-9)   # of the machine, what the work got
                ratio = r["cpu"] / max(idle["cpu"], 1e-9)
                print(f"  {work} ({n} {'batches of 16 crops x 11 passes' if work == 'features' else 'images, batch 64'}),"
                      f" {route}, {c}: wall {r['wall']:.1f} s, CPU {r['cpu']:.1f} s, CPU/idle {ratio:.2f}x"
                      f"{'' if c == 'idle' else (' (goal <= 1.3x: ' + ('met' if ratio <= GOAL else 'NOT met') + ')')}, "
                      f"share of the machine {share:.2f}, wall/idle {r['wall'] / max(idle['wall'], 1e-9):.2f}x, "
                      f"threads (count: intervals) {r['threads']}, load average before {r['load']:.1f}", flush=True)
    return {"ratios": {f"{w} {r}": {c: v["cpu"] / max(runs['idle']['cpu'], 1e-9) for c, v in runs.items()}
                       for (w, r), runs in res.items()}}


if __name__ == "__main__":
    main()
