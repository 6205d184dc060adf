"""Typed, validated TOML configuration: the one import for the rest of the project.

Every section is a frozen dataclass. Loading checks each key against the dataclass: an unknown
key, a wrong type or an out-of-range value raises ``ConfigError`` naming the file and the dotted
key, and the cross-key checks of every section run before any stage does. Stages hash only the
sections they declare (see ``stages.framework.registry``), so an edit to one section reruns only the stages
that read it.

The modules, by meaning: ``fields`` (the error and the field every section is made of), the sections
of what a run reads (``inputs``: run, data), of the scorer and the class models (``learning``:
classifier, features, models), of the evaluation (``evaluation``: evaluate, report), of the
simulation (``simulate``), view planning (``plan``), the root ``Config`` (``root``, with study), loading (``load``) and the
cross-key checks (``checks``).
"""
from __future__ import annotations

from pipeline.infra.config.checks import bounds_problem, check_simulate, cross_checks
from pipeline.infra.config.load import ablation_config, load_config, merge, parse_override
from pipeline.infra.config.evaluation import (ABLATION_KEYS, BiasedConfig, BiasedRandomizedConfig, BiasMapsConfig, EvaluateConfig,
                                             RandomizedConfig, ReportConfig, SensitivityConfig, fit_only_banks,
                                             is_model_ablation)
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.inputs import DEFAULT_INSTANCES, DataConfig, RunConfig, SyntheticDataConfig
from pipeline.infra.config.learning import ClassifierConfig, FeaturesConfig, ModelsConfig, TrainingConfig
from pipeline.infra.config.plan import PlanConfig
from pipeline.infra.config.root import Config, StudyConfig, canonical_json, domain_variance_mode, to_dict
from pipeline.infra.config.simulate import SimulateConfig


__all__ = [
    "ABLATION_KEYS", "DEFAULT_INSTANCES", "BiasedConfig", "BiasedRandomizedConfig", "BiasMapsConfig", "ClassifierConfig", "Config",
    "ConfigError", "DataConfig", "EvaluateConfig", "FeaturesConfig", "ModelsConfig", "PlanConfig", "RandomizedConfig",
    "ReportConfig", "RunConfig", "SensitivityConfig", "SimulateConfig", "StudyConfig", "SyntheticDataConfig",
    "TrainingConfig", "ablation_config", "bounds_problem", "canonical_json", "check_simulate", "cross_checks",
    "fit_only_banks",
    "is_model_ablation", "load_config", "merge", "parse_override", "domain_variance_mode", "to_dict",
]
