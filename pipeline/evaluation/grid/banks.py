"""The run's model banks as the evaluate stage reads them from its models folder: the default's,
each ablation's and the contrast's arm (``load_banks``), the fit-only banks of
``evaluate.fit_spaces`` (loaded one at a time: ``fit_bank_loaders``) and the models of the
registered providers (``load_provided``, ``variant_provided``)."""
from __future__ import annotations

import functools
from pathlib import Path

from pipeline.evaluation.grid.contrast import ARM as CONTRAST_ARM
from pipeline.evaluation.grid.population import DEFAULT
from pipeline.infra.config import Config, fit_only_banks, is_model_ablation
from pipeline.infra.outputs import name as out_name
from pipeline.method.gp_files import load_bank, read_bank_index
from pipeline.method.registry import model_providers


def load_banks(models_dir: Path, ablations: tuple[str, ...]) -> tuple[dict, dict]:
    """{variant: model bank} and {variant: models/index.json} for the default and every ablation (an
    evaluate.* ablation shares the default's bank and index: the same objects) and the contrast's arm."""
    index = read_bank_index(models_dir)
    banks, indexes = {DEFAULT: load_bank(models_dir)}, {DEFAULT: index}
    for a in ablations:
        if not is_model_ablation(a):  # an evaluate.* variant: same models, another likelihood
            banks[a], indexes[a] = banks[DEFAULT], index
            continue
        sub = index.get("ablations", {}).get(a)
        if sub is None:
            raise ValueError(f"{models_dir / out_name('models', 'index')}: no model bank for ablation {a!r} "
                             "(rerun the models stage)")
        banks[a] = load_bank(models_dir / sub)
        indexes[a] = read_bank_index(models_dir / sub)
    arm = models_dir / out_name("models", "contrast")
    if arm.is_dir():   # data.real_imagery.contrast: the instance arm runs as one more variant on the same tracks
        banks[CONTRAST_ARM], indexes[CONTRAST_ARM] = load_bank(arm), read_bank_index(arm)
    return banks, indexes


def fit_bank_loaders(models_dir: Path, cfg: Config, index: dict) -> dict:
    """{fit-only bank: a function that loads it} for every ``evaluate.fit_spaces`` bank the run
    fits (``fit_only_banks``), from ``models/index.json``'s ``fit_banks``; loaded one at a time by
    the test-domain fit, never held beside the cells."""
    where, out = index.get("fit_banks") or {}, {}
    for a in fit_only_banks(cfg):
        if a not in where:
            raise ValueError(f"{models_dir / out_name('models', 'index')}: no fit-only model bank {a!r} for "
                             "evaluate.fit_spaces (rerun the models stage)")
        out[a] = functools.partial(load_bank, models_dir / where[a])
    return out


def variant_provided(models_dir: Path, cfg: Config) -> dict:
    """{variant: {provider key: its models}} where a variant's classes were fitted on another
    training set (the contrast's instance arm, ``models/contrast/<key>/``; a provider that follows
    the default bank only has none there)."""
    d = models_dir / out_name("models", "contrast")
    return {CONTRAST_ARM: load_provided(d, cfg, variant=True)} if d.is_dir() else {}


def load_provided(models_dir: Path, cfg: Config, variant: bool = False) -> dict:
    """{provider key: its models} of every provider the registered methods need and the config
    enables (``models/<key>/``); of a ``variant``'s folder, without those that follow the default
    bank only."""

    return {p.key: p.load(models_dir / p.key, cfg) for p in model_providers(cfg) if not (variant and p.default_only)}
