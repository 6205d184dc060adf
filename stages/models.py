"""``models`` stage: plan each target's candidate set and components, fit the GPs they need.

Wiring only: reads ``features/bigbird.parquet`` through ``pipeline.banks.model_bank`` (the
checks, training sets, candidate plan, noise floor and fits) and writes one model bank,
``models/index.json`` + one ``<class>.npz`` per class (``pipeline.method.gp.GPClassModels``):
every modelled class x every component that some target's candidate set uses, with the plan in
the index (``candidate_sets``). Each ``evaluate.ablations`` entry gets its own bank under
``models/ablations/``, and so does each ``evaluate.fit_spaces`` bank (index ``fit_banks``: fitted for
the test-domain fit alone, no cell runs on it). Beside the bank, the models of every provider a registered method needs
(``pipeline.method.provider``; those the config enables), each in ``models/<provider key>/``. With
``data.real_imagery.contrast``, the contrast's instance arm (``models/contrast/``: a bank on the same
plan keys and features, each class fitted on its own instance, and its methods' own models but
those that follow the default bank only, ``ModelProvider.default_only``).
"""
from __future__ import annotations

import logging

from loaders.real_imagery.category import class_members, contrast_members
from pipeline.banks.model_bank import ablation_dir, fit_from_features, training_views
from pipeline.method.registry import model_providers
from pipeline.method.gp_files import save_bank
from pipeline.infra.config import ablation_config, fit_only_banks, is_model_ablation
from pipeline.infra.outputs import name as out_name
from pipeline.infra.outputs import read as read_artifact
from pipeline.infra.budget import budget
from pipeline.infra.device import free_cores
from pipeline.method.gp_workers import fit_workers

log = logging.getLogger("viewfuse.models")


def contrast_check(first: dict, second: dict) -> None:
    """The two arms of the contrast score the same candidates per target (drawn from the same
    classes; only the component choice may differ with the training set), else the pairing breaks."""
    differ = sorted(t for t in set(first) | set(second)
                    if (first.get(t) or {}).get("classes") != (second.get(t) or {}).get("classes"))
    if differ:
        raise ValueError(f"data.real_imagery.contrast: the instance arm's candidate sets differ from the category "
                         f"arm's for {len(differ)} target(s) (first: {differ[0]}); a candidate rule that reads the "
                         f"training scores (evaluate.candidates) cannot pair the arms")


def run(ctx) -> str:
    # the GP fits go to worker processes: run.threads of them, or (0) as many as cores are free
    # now; the models do not depend on the count (pipeline/method/gp_workers.py)
    with fit_workers(ctx.threads or free_cores(), budget(ctx.cfg)):
        return _run(ctx)


def _run(ctx) -> str:
    cfg = ctx.cfg
    ev = cfg.evaluate
    feats = ctx.input("features") / out_name("features", "bigbird")
    # category classes: several objects' views per class, as the data stage made them
    truth = read_artifact(ctx.input("data"), "data", "truth", missing=None)
    members = class_members(cfg, truth)
    plan_keys = dict(targets=ev.targets, n_candidates=ev.n_candidates, candidates=ev.candidates,
                     candidate_seed=ev.candidate_seed, candidate_folds=ev.candidate_folds, class_members=members,
                     fit_cache={})   # one fit per distinct (data, settings, starts) across the banks below
    models, extra = fit_from_features(feats, cfg.models, **plan_keys)
    model_ablations = [a for a in ev.ablations if is_model_ablation(a)]  # others reuse the default bank
    extra["ablations"] = {a: ablation_dir(a) for a in model_ablations}
    fit_only = fit_only_banks(cfg)   # evaluate.fit_spaces: read by the test-domain fit only
    extra["fit_banks"] = {a: ablation_dir(a) for a in fit_only}
    save_bank(models, ctx.out, extra=extra)
    provided = fit_providers(ctx, feats, models.classes, extra["candidate_sets"], members, plan_keys)
    arm = contrast_members(cfg, truth)
    if arm is not None:   # data.real_imagery.contrast: the instance arm, same features and plan keys
        log.info("the contrast's instance arm: fitting its model bank and its methods' own models")
        cm, cextra = fit_from_features(feats, cfg.models, **{**plan_keys, "class_members": arm})
        contrast_check(extra["candidate_sets"], cextra["candidate_sets"])
        cdir = ctx.out / out_name("models", "contrast")
        save_bank(cm, cdir, extra={**cextra, "class_members": arm})
        fit_providers(ctx, feats, cm.classes, cextra["candidate_sets"], arm, {**plan_keys, "class_members": arm},
                      folder=cdir, prefix="contrast_")
        ctx.extra["contrast_classes"] = len(arm)
    for a in (*model_ablations, *fit_only):
        vcfg = ablation_config(cfg, a)
        log.info("%s %s: fitting its model bank", "fit-only bank" if a in fit_only else "ablation", a)
        vm, vextra = fit_from_features(feats, vcfg.models, **plan_keys)
        save_bank(vm, ctx.out / ablation_dir(a), extra={**vextra, "ablation": a, "fit_only": a in fit_only})
    ctx.extra.update({"classes": models.classes, "components": models.components,
                      "component_names": models.component_names,
                      "candidate_sets": len(extra["candidate_sets"]),
                      "fits_with_warnings": extra["fits_with_warnings"],
                      "varying_fits_at_bound": extra["varying_fits_at_bound"]})
    return (f"{models.n_classes} classes x {models.n_components} components for "
            f"{len(extra['candidate_sets'])} candidate sets ({cfg.models.component_rule}) fitted on "
            f"{extra['features']['rows_used']} views; {extra['fits_with_warnings']} fit(s) with warnings, "
            f"{extra['varying_fits_at_bound']} varying component(s) at a bound"
            + (f"; {len(model_ablations)} ablation bank(s)" if model_ablations else "")
            + (f"; {len(fit_only)} fit-only bank(s) ({', '.join(a.split('=', 1)[1] for a in fit_only)})"
               if fit_only else "")
            + "".join(f"; {p}" for p in provided))


def fit_providers(ctx, feats, classes, plan: dict, members, plan_keys: dict, folder=None,
                  prefix: str = "") -> list[str]:
    """Fit and save every enabled provider's models (``<folder>/<key>/``, by default
    ``models/<key>/``), recording each one's digest and record in the stage's extras under
    ``prefix``; returns their summary clauses. ``plan_keys``: ``fit_from_features``' for a
    provider's bank-like model (``TrainingViews.fit_bank``). Another folder is a variant's
    (``prefix``): a provider that follows the default bank only is not fitted there."""
    folder = ctx.out if folder is None else folder
    views, out = None, []
    for p in model_providers(ctx.cfg):
        if prefix and p.default_only:
            log.info("%s: fitted for the default model bank only, not in %s", p.label or p.key, folder.name)
            continue
        if views is None:   # one read of the training views for every provider
            views = training_views(feats, ctx.cfg.models.camera, classes, plan, class_members=members,
                                   fit_bank=lambda fit: fit_from_features(feats, ctx.cfg.models, **plan_keys, fit=fit))
        log.info("fitting the %s", p.label or f"{p.key} models")
        pm, pextra = p.fit(views, ctx.cfg)
        p.save(pm, folder / p.key, pextra)
        ctx.extra[f"{prefix}{p.key}_fingerprint"] = p.digest(pm)
        ctx.extra.update({f"{prefix}{p.key}_{k}": v for k, v in p.record(pm, pextra).items()})
        out.append(p.summary(pm, pextra, ctx.cfg))
    return out
