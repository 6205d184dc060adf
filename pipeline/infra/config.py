"""Typed, validated TOML configuration: the one import for the rest of the project.

Every section is a frozen dataclass. Loading checks each key against the dataclass: an unknown
key, a wrong type or an out-of-range value raises ``ConfigError`` naming the file and the dotted
key, and the cross-key checks of every section run before any stage does. Stages hash only the
sections they declare (see ``stages.registry``), so an edit to one section reruns only the stages
that read it.

The code lives in three modules: the schema (``config_schema``: run, data, classifier, features,
models; ``config_sections``: evaluate, report, simulate, study and the root ``Config``), loading
(``config_load``) and the cross-key checks (``config_checks``).
"""
from __future__ import annotations

from pipeline.infra.config_checks import bounds_problem, check_simulate, cross_checks
from pipeline.infra.config_load import ablation_config, load_config, merge, parse_override
from pipeline.infra.config_schema import (DEFAULT_INSTANCES, ClassifierConfig, ConfigError, DataConfig,
                                          FeaturesConfig, ModelsConfig, RunConfig, SyntheticDataConfig,
                                          TrainingConfig)
from pipeline.infra.config_sections import (ABLATION_KEYS, BiasedConfig, BiasMapsConfig, Config,
                                            EvaluateConfig, RandomizedConfig, ReportConfig, SensitivityConfig,
                                            SimulateConfig, StudyConfig, canonical_json, is_model_ablation,
                                            test_domain_mode, to_dict)


__all__ = [
    "ABLATION_KEYS", "DEFAULT_INSTANCES", "BiasedConfig", "BiasMapsConfig", "ClassifierConfig", "Config",
    "ConfigError", "DataConfig", "EvaluateConfig", "FeaturesConfig", "ModelsConfig", "RandomizedConfig",
    "ReportConfig", "RunConfig", "SensitivityConfig", "SimulateConfig", "StudyConfig", "SyntheticDataConfig",
    "TrainingConfig", "ablation_config", "bounds_problem", "canonical_json", "check_simulate", "cross_checks",
    "is_model_ablation", "load_config", "merge", "parse_override", "test_domain_mode", "to_dict",
]
