"""Stage ``simulate``: the simulation scenarios of the paper's §5.3 (no imagery needed).

Fits the three hand-specified class models, runs every configured scenario over
``simulate.realizations`` realizations with all three methods, and writes into the stage folder:

- ``results.parquet``: one row per (scenario, realization, step, method): posterior, P(truth),
  log10 MGR, MSDE, correct (written by ``pipeline.evaluation.metrics.results``, as evaluate's); metadata:
  classes, truth, config hash, seed.
- ``example.parquet``: the example realization's measurements per (scenario, step, component),
  with every class's GP mean/std along the track (the measurement figures).
- ``summary.json``: the table (every metric of ``pipeline.evaluation.metrics.spec``), the findings checks,
  the paper's §5.3 claims checked (``claims``: statistic, 95 % CI, holds), the confident-error rate
  per step (``confident_errors``), the regime sweep over GP noise x σ_max (``sweep``, unless
  ``simulate.sweep = "off"``) and the claims re-run at full size where most of them hold
  (``best_regime``), GP fit diagnostics, seeds and timings.
- ``models/``: the fitted simulation GPs (``index.json`` + ``.npz``, no pickles).
- ``index.html`` + PNGs (``reports.simulate.page``: log10 MGR, shared method names, CIs over realizations).
"""
from __future__ import annotations

import dataclasses
import logging
import time

from pipeline.infra import footprints
from pipeline.infra.budget import budget, cap_batch, require
from pipeline.infra.cache import write_json
from pipeline.infra.config import Config, to_dict
from pipeline.infra.outputs import name as out_name
from pipeline.infra.progress import bar as progress_bar
from pipeline.evaluation.metrics.results import frame, metadata, write_results
from pipeline.evaluation.metrics.spec import Params
from pipeline.method.gp_files import save_bank

log = logging.getLogger("viewfuse.simulate")


def _fit_budget(sim, limit: int):
    """The results of every realization are kept (refused when they cannot fit); a fused batch
    holds ``simulate.chunk`` realizations (capped to a quarter of the budget; the results do not
    depend on it: every realization draws from its own generator)."""
    from pipeline.evaluation.simulation.scenarios import methods  # heavy: pandas
    rows = sim.realizations * len(sim.scenarios) * len(methods()) * sim.track_steps  # (method, realization, step)
    require("simulate.realizations", sim.realizations, footprints.simulate_results(sim, len(methods())), limit,
            f"the results table ({rows} rows, kept in memory until written)")
    chunk = cap_batch("simulate.chunk", sim.chunk, footprints.simulate_realization(sim), limit / 4)
    return dataclasses.replace(sim, chunk=chunk) if chunk != sim.chunk else sim


def run(ctx) -> str:
    cfg: Config = ctx.cfg
    sim = _fit_budget(cfg.simulate, budget(cfg))  # before the heavy imports below: a refusal is immediate
    from pipeline.evaluation.simulation import scenarios as S  # heavy: pandas
    from pipeline.evaluation.simulation import sweep as SW  # heavy: scipy
    from reports.simulate.findings import findings  # heavy: pandas
    from reports.simulate.page import build_simulate_report  # heavy: pandas

    S.validate(sim, cfg.source_path or "config")
    t_start = time.perf_counter()
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    fitted, diags = S.fit_models(sim)
    models = S.configured_models(fitted, sim)
    save_bank(models, ctx.out / out_name("simulate", "models"), extra={"fit_diagnostics": diags, "source": "simulate"})
    timings["fit"] = time.perf_counter() - t0
    # Hyperparameters at a bound are expected here (the bounds are tight on purpose, see the
    # config); they are listed in summary.json and the report. Other optimizer warnings are not.
    n_bound = sum(len(d["at_bound"]) for d in diags)
    if n_bound:
        log.info("GP fits: %d hyperparameter(s) at a bound of the [simulate] *_bounds (listed in the report)", n_bound)
    for d in diags:
        other = [w for w in d["warnings"] if "close to the specified" not in w]
        if other:
            log.warning("GP %s / component %d: %s", d["class"], d["component"], "; ".join(other))

    blocks, examples, posts = [], [], {}
    with progress_bar(total=sim.realizations * len(sim.scenarios), desc="simulate", unit="realization") as bar:
        for scenario in sim.scenarios:
            t0 = time.perf_counter()
            res = S.run_scenario(models, scenario, sim, progress=bar.update)
            blocks.append(S.result_columns(res))
            posts[scenario] = res.posteriors
            examples.append(S.example_columns(res, models))
            timings[scenario] = time.perf_counter() - t0
    meta = dict(classes=list(sim.class_names), truth=str(sim.truth_class - 1),
                config_hash=cfg.section_hash("simulate"), seed=str(sim.seed))
    n_rows = write_results(blocks, ctx.out / out_name("simulate", "results"), metadata(**meta))
    write_results(examples, ctx.out / out_name("simulate", "example"),
                  metadata(**meta, example_realization=str(sim.example_realization)))
    df, ex = frame(blocks, drop=("posterior",)), frame(examples)

    table = S.summarize(df, Params.of(sim))
    found = findings(df, ex, sim.truth_class - 1, posts, sim.confident_threshold)
    block, t_claims = SW.claims_block(fitted, models, sim, posts)
    timings.update(t_claims)
    write_json(ctx.out / out_name("simulate", "summary"), {
        "table": table.to_dict(orient="records"),
        "findings": found,
        **block,   # claims, claim_params, confident_errors, sweep, best_regime
        "classes": list(sim.class_names), "truth": sim.truth_class - 1,
        "seed": sim.seed, "config_hash": meta["config_hash"],
        "config": to_dict(sim),
        "gp_fit": diags,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    })

    t0 = time.perf_counter()
    rep = build_simulate_report(ctx.out, ctx.out, dpi=sim.dpi, run_name=cfg.run.name)
    timings["report"] = time.perf_counter() - t0
    ctx.extra["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
    ctx.extra["figures"] = rep.figures

    took = time.perf_counter() - t_start
    parts = [f"{len(sim.scenarios)} scenario(s) x {sim.realizations} realizations, {n_rows} rows",
             f"paper claims holding: {sum(c['holds'] for c in block['claims'])} of {len(block['claims'])}"]
    for _, r in table.iterrows():
        parts.append(f"{r['scenario']}/{r['method']} correct(final)={r['correct_final']:.2f}")
    final = cfg.stage_dir(ctx.stage) / out_name("simulate", "html")
    return "; ".join(parts) + f"; {len(rep.figures)} figures in {took:.1f} s; open {final}"
