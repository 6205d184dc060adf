"""Re-measure the cost model's per-unit constants (pipeline/infra/cost.py) on this machine.

Prints, for each unit the model uses, the seconds measured here on a small run next to the
constant in cost.py and their ratio (> 1: this machine, at its present load, is slower than the
constant says): With Uncertainty trajectories at (K, C) = (9, 4), (18, 4), (9, 8) (the K^1.5 and
C^0.75 scaling), simulate's two scenarios per realization, the MC-dropout head per row and the
backbone per crop (AlexNet, 112 px). Also the resident memory after importing each stage's
modules (cost.BASE). Takes about a minute.

    python tests/bench/bench_cost.py
"""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pipeline.infra import cost  # noqa: E402


def best(fn, n: int = 2) -> float:
    out = np.inf
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out = min(out, time.perf_counter() - t)
    return out


def line(what: str, measured: float, model: float) -> None:
    print(f"{what:58s} measured {measured * 1e3:9.3f} ms  model {model * 1e3:9.3f} ms  ratio {measured / model:5.2f}")


def trajectories() -> None:
    from pipeline.method.fusion import fuse_with_uncertainty
    from tests.bench.bench_fusion import tracks, workload

    for C, K in ((4, 9), (4, 18), (8, 9)):
        models = workload(C=C)
        models.factors()
        X, Z = tracks(np.random.default_rng(0), 40, 50, K, 10, 4)
        fuse_with_uncertainty(models, X[:2], Z[:2], progress=False)   # compile
        s = best(lambda: fuse_with_uncertainty(models, X, Z, progress=False)) / (40 * 50)
        line(f"With Uncertainty trajectory, K = {K}, C = {C}", s, cost.WU_TRAJECTORY_S * cost._wu_scale(K, C))


def simulate() -> None:
    from pipeline.evaluation.simulation import scenarios as S
    from pipeline.infra.config import Config

    sim = dataclasses.replace(Config().simulate, restarts=0)
    t = time.perf_counter()
    models = S.configured_models(S.fit_models(sim, progress=False)[0], sim)
    line("simulate GP fits, per start", time.perf_counter() - t, cost.SIM_FIT_S)
    for scenario, reals, model in (("model_uncertainty", 20, cost.SIM_MU_S + cost.SIM_MU_SAMPLE_S * sim.n_samples),
                                   ("localization_bias", 10, cost.SIM_LB_SAMPLE_S * sim.n_loc_samples)):
        s = dataclasses.replace(sim, realizations=reals)
        line(f"simulate {scenario}, per realization", best(lambda: S.run_scenario(models, scenario, s)) / reals, model)


def network() -> None:
    import torch
    from torchvision.models import alexnet

    m = alexnet(num_classes=12).eval()
    for mod in m.classifier:
        if isinstance(mod, torch.nn.Dropout):
            mod.train()
    rows, crops = torch.randn(2048, 9216), torch.randn(64, 3, 112, 112)
    with torch.no_grad():
        line("MC-dropout head, per (crop, sample) row", best(lambda: m.classifier(rows)) / 2048, cost.HEAD_ROW_S)
        line("AlexNet backbone, per 112 px crop", best(lambda: m.avgpool(m.features(crops))) / 64, cost.BACKBONE_CROP_S)


def imports() -> None:
    code = ("import importlib, psutil; from stages.framework.registry import STAGES, code_version\n"
            "for m in code_version(STAGES[{s!r}])[1]: importlib.import_module(m)\n"
            "i = psutil.Process().memory_info(); print(i.rss, i.vms)")
    for stage, base in cost.BASE.items():
        out = subprocess.run([sys.executable, "-c", code.format(s=stage)], cwd=ROOT, capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
        rss, vms = map(int, out.stdout.split())
        print(f"{stage:10s} imports: {rss / 2**30:5.2f} GiB resident (model {base / 2**30:4.2f}), "
              f"{vms / 2**30:5.2f} GiB mapped")


def main() -> None:
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    trajectories()
    simulate()
    network()
    imports()


if __name__ == "__main__":
    main()
