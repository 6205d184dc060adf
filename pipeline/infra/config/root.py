"""The root ``Config`` (every section, the run's derived locations) with ``[study]``, and the
canonical forms a config is hashed and written in."""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.infra.cache import sha256_bytes
from pipeline.infra.config.fields import SEED_MAX, setting as _f
from pipeline.infra.config.evaluation import TEST_DOMAIN_MODES, EvaluateConfig, ReportConfig
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.inputs import DataConfig, RunConfig
from pipeline.infra.config.learning import ClassifierConfig, FeaturesConfig, ModelsConfig
from pipeline.infra.config.own import own_items
from pipeline.infra.config.plan import PlanConfig
from pipeline.infra.config.simulate import SimulateConfig


# The settings that name files or folders. A relative one resolves against the project root of the
# config file that sets it (``project_root``), so a key inherited through ``extends`` from
# configs/synthetic.toml means the same folder whichever file extends it.
PATH_KEYS = ("run.artifacts", "run.stage_cache", "data.bigbird_root", "data.avd_root", "classifier.path", "data.coil_root",
             "data.eth80_root", "data.avd_frames_root")


def project_root(config_file: str | Path) -> Path:
    """The parent of ``configs/`` for a file there, else the file's own folder."""
    p = Path(config_file).resolve().parent
    return p.parent if p.name == "configs" else p


@dataclass(frozen=True)
class StudyConfig:
    seeds: tuple[int, ...] = _f(factory=lambda: (0, 1, 2), lo=0, hi=SEED_MAX,
                                doc="classifier seeds: classifier -> features -> models -> evaluate once "
                                    "per seed under <run>/study/seed-<n>/ (data shared with the run)")


@dataclass(frozen=True)
class Config:
    run: RunConfig = _f(factory=RunConfig)
    data: DataConfig = _f(factory=DataConfig)
    classifier: ClassifierConfig = _f(factory=ClassifierConfig)
    features: FeaturesConfig = _f(factory=FeaturesConfig)
    models: ModelsConfig = _f(factory=ModelsConfig)
    evaluate: EvaluateConfig = _f(factory=EvaluateConfig)
    plan: PlanConfig = _f(factory=PlanConfig)
    report: ReportConfig = _f(factory=ReportConfig)
    simulate: SimulateConfig = _f(factory=SimulateConfig)
    study: StudyConfig = _f(factory=StudyConfig)
    # Where the config file lives; relative paths in it resolve against its project root.
    source_path: str = field(default="", compare=False, metadata={"internal": True})
    # (path key, project root of the file that set it) for each PATH_KEYS entry set in a file of
    # the `extends` chain: a path resolves against the root of the file it is written in.
    path_roots: tuple[tuple[str, str], ...] = field(default=(), compare=False, metadata={"internal": True})

    # -- derived locations -------------------------------------------------------------------
    @property
    def root(self) -> Path:
        """Project root: the parent of ``configs/`` for files there, else the file's folder."""
        return project_root(self.source_path) if self.source_path else Path.cwd()

    def resolve(self, path: str, key: str | None = None) -> Path:
        """``path`` made absolute: against the project root of the file that set ``key`` (see
        ``path_roots``), else against this config's own root."""
        p = Path(path).expanduser()
        if p.is_absolute():
            return p
        return Path(dict(self.path_roots).get(key, self.root)) / p

    def path(self, key: str) -> Path:
        """The path setting ``key`` (one of PATH_KEYS, e.g. ``data.avd_root``), resolved."""
        return self.resolve(self.section(key), key)

    @property
    def artifacts_dir(self) -> Path:
        """The artifacts root, absolute and normalised (``..`` folded away)."""
        return Path(os.path.abspath(self.path("run.artifacts")))

    @property
    def run_dir(self) -> Path:
        return self.artifacts_dir / self.run.name

    def stage_dir(self, stage: str) -> Path:
        return self.run_dir / stage

    def section(self, name: str) -> Any:
        """A section or, dotted, one key (``evaluate.candidates``): a stage may depend on single keys."""
        obj = self
        for part in name.split("."):
            obj = getattr(obj, part)
        return obj

    def section_hash(self, name: str) -> str:
        return sha256_bytes(canonical_json(to_dict(self.section(name))).encode())


def domain_variance_mode(cfg: Config, ablation: str | None) -> str:
    """``evaluate.test_domain_variance`` of the default run (None) or of one ablation variant."""
    if ablation is not None and "=" in ablation:
        key, raw = (t.strip() for t in ablation.split("=", 1))
        if key == "evaluate.test_domain_variance":
            value = raw.strip("'\"")
            if value not in TEST_DOMAIN_MODES:
                raise ConfigError(f"evaluate.ablations: {ablation!r}: the value must be none or cross_fit")
            return value
    return cfg.evaluate.test_domain_variance


# ----------------------------------------------------------------------------------------------
def to_dict(obj: Any) -> Any:
    """Plain (JSON-able) form of a config or section."""
    if dataclasses.is_dataclass(obj):
        out = {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)
               if not f.metadata.get("internal")}
        out.update((k, to_dict(v)) for k, v in own_items(obj))   # extensions' sections, where the TOML has them
        return out
    if isinstance(obj, (tuple, list)):
        return [to_dict(v) for v in obj]
    return obj


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)
