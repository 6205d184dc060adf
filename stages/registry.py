"""The stage graph: what each stage reads (config sections, code, upstream stages).

A stage's cache key is the hash of exactly these, DVC-style: editing one config section reruns
the stages that declare it and those downstream of them, nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class StageSpec:
    name: str
    module: str                          # has run(ctx) -> str (one-line summary)
    upstream: tuple[str, ...] = ()
    sections: tuple[str, ...] = ()       # config sections hashed into the key
    code: tuple[str, ...] = ()           # modules/packages whose source is hashed into the key
    help: str = ""
    after: tuple[str, ...] = field(default=())  # stages run right after this one by the CLI


STAGES: dict[str, StageSpec] = {s.name: s for s in (
    StageSpec("data", "stages.data", (), ("data",),
              ("stages.data", "loaders.synthetic", "loaders.pbm", "loaders.errors", "loaders.avd",
               "loaders.bigbird", "pipeline.cache"),
              "render the synthetic BigBIRD/AVD stand-ins, or validate the real dataset paths"),
    StageSpec("classifier", "stages.classifier", (), ("classifier",),
              ("stages.classifier", "pipeline.classifier", "pipeline.source_domain", "pipeline.crops",
               "pipeline.cache", "loaders.synthetic.textures"),
              "resolve the dropout AlexNet weights (train the synthetic source-domain model)"),
    StageSpec("features", "stages.features", ("data", "classifier"), ("features",),
              ("stages.features", "pipeline.features", "pipeline.classifier", "pipeline.crops",
               "pipeline.cache", "loaders.bigbird", "loaders.avd", "loaders.errors", "loaders.pbm"),
              "crop every needed view and score it (deterministic pass + MC dropout) -> Parquet"),
    StageSpec("models", "stages.models", ("features",),
              ("models", "evaluate.targets", "evaluate.n_candidates", "evaluate.candidates",
               "evaluate.candidate_seed", "evaluate.ablations"),
              ("stages.models", "pipeline.gp", "pipeline.components", "pipeline.candidates", "pipeline.config",
               "pipeline.cache"),
              "choose feature components and fit one GP per (class, component)"),
    StageSpec("evaluate", "stages.evaluate", ("data", "features", "models"), ("evaluate",),
              ("stages.evaluate", "pipeline.experiments", "pipeline.track", "pipeline.fusion",
               "pipeline.gp", "pipeline.geometry", "pipeline.metrics", "pipeline.features", "loaders.avd"),
              "build the AVD track and run the localization-error experiments", after=("report",)),
    StageSpec("report", "stages.report", ("models", "evaluate"), ("report",),
              ("stages.report", "reports", "loaders.errors", "pipeline.cache", "pipeline.metrics"),
              "render the HTML + PNG report from existing results"),
    StageSpec("simulate", "stages.simulate", (), ("simulate",),
              ("stages.simulate", "pipeline.simulation", "pipeline.fusion", "pipeline.gp",
               "pipeline.geometry", "pipeline.metrics", "reports.simulate_report", "reports.html",
               "reports.figures"),
              "simulation scenarios of the paper's section 5.3 (synthetic GP measurements)"),
)}

ORDER = ("data", "classifier", "features", "models", "evaluate", "report", "simulate")
