"""Leave-one-instance-out judgement of the instance term's prior on a category run's features
(pipeline/evaluation/instance_loio.py; docs/results.md, "Instance term: a prior on the variance
split"). Usage, after `viewfuse features --config configs/real_category.toml`:
    python tools/instance_loio.py --config configs/real_category.toml [--spaces probability log]
        [--features artifacts/real_category/features/bigbird.parquet] [--out artifacts/instance_loio.json]
The training views (models.targets: the MC-dropout mean per view) of every ETH-80 instance; each
space's fits take [models]'s bounds and priors, with --log-noise overriding the noise bounds and
noise prior in the log spaces (a log score's noise is not a probability's)."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def load(config: str, features: str | None, sets: list[str]):
    """(the config, {category: {instance folder: (X (n, 2), S (n, D))}}) from the features file."""
    from loaders.real_imagery.category import class_members
    from pipeline.banks.model_bank import _training_sets
    from pipeline.infra.config import load_config, merge, parse_override
    from pipeline.scene.folds import category_of

    overrides: dict = {}
    for o in sets:
        overrides = merge(overrides, parse_override(o))
    cfg = load_config(config, overrides or None)
    members = class_members(cfg)
    if members is None:
        raise SystemExit(f"{config}: not an ETH-80 category run (data.real_imagery.dataset = 'eth80')")
    path = Path(features or cfg.stage_dir("features") / "bigbird.parquet")
    if not path.is_file():
        raise SystemExit(f"{path}: no features file (run `viewfuse features --config {config}` first)")
    pool, X_by, S_by, *_ = _training_sets(path, cfg.models)
    cat_of = {m: category_of(cls) for cls, ms in members.items() for m in ms}
    data: dict = {}
    for obj in pool:
        if obj in cat_of:
            data.setdefault(cat_of[obj], {})[obj] = (X_by[obj], np.asarray(S_by[obj], float))
    return cfg, data, path


def main(argv=None) -> int:
    from pipeline.evaluation.instance_loio import Settings, judge

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/real_category.toml")
    ap.add_argument("--set", action="append", default=[], help="config override KEY=VALUE")
    ap.add_argument("--features", default=None)
    ap.add_argument("--spaces", nargs="+", default=["probability", "log"])
    ap.add_argument("--top", type=int, default=2, help="components per category, pooled per fold")
    ap.add_argument("--split-prior", type=float, nargs=2, default=(2.0, 2.0))
    ap.add_argument("--log-noise", type=float, nargs=4, default=(1e-6, 10.0, 1e-4, 1.0),
                    metavar=("LO", "HI", "PRIOR_LO", "PRIOR_HI"), help="noise bounds and noise prior in log spaces")
    ap.add_argument("--bootstrap", type=int, default=2000)
    ap.add_argument("--out", default="artifacts/instance_loio.json")
    a = ap.parse_args(argv)
    cfg, data, path = load(a.config, a.features, a.set)
    m = cfg.models
    out = {"config": a.config, "features": str(path), "categories": sorted(data),
           "instances": {c: sorted(v) for c, v in data.items()}, "spaces": {}}
    for space in a.spaces:
        fit = dict(restarts=m.restarts, amplitude_bounds=tuple(m.amplitude_bounds),
                   length_scale_bounds=tuple(m.length_scale_bounds), noise_bounds=tuple(m.noise_bounds),
                   seed=m.seed, hyperprior=m.hyperprior, noise_prior=tuple(m.noise_prior))
        if space != "probability":
            fit.update(noise_bounds=tuple(a.log_noise[:2]), noise_prior=tuple(a.log_noise[2:]))
        st = Settings(space=space, floor=m.score_floor, top=a.top, split_prior=tuple(a.split_prior), fit=fit,
                      n_boot=a.bootstrap)
        t0 = time.perf_counter()
        res = judge(data, st)
        res["seconds"] = time.perf_counter() - t0
        res["fit"] = {k: list(v) if isinstance(v, tuple) else v for k, v in fit.items()}
        out["spaces"][space] = res
        print(json.dumps({space: res}, indent=1), flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
