"""Config schema, second part: the evaluation sections (evaluate, report, simulate, study) and the
root ``Config`` with the run's derived locations."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.infra.config_schema import (ClassifierConfig, ConfigError, DataConfig, FeaturesConfig, ModelsConfig,
                                          RunConfig, SEED_MAX, _f)


@dataclass(frozen=True)
class BiasedConfig:
    bias_m: tuple[float, ...] = _f(factory=lambda: (-0.30, 0.20), lo=-100.0, hi=100.0, doc="[x, y] metres")
    sigma_m: float = _f(0.30, lo=0.0, hi=10.0)
    n_loc_samples: int = _f(50, lo=1, hi=100000)


@dataclass(frozen=True)
class RandomizedConfig:
    bias_m: tuple[float, ...] = _f(factory=lambda: (0.0, 0.0), lo=-100.0, hi=100.0, doc="[x, y] metres")
    sigmas_m: tuple[float, ...] = _f(factory=lambda: (0.1, 0.3, 0.5), lo=0.0, hi=10.0,
                                     doc="one population setting per sigma: estimate = truth + bias + N(0, sigma^2 I)")
    realizations: int = _f(20, lo=1, hi=1000000, doc="realizations per (target, track, sigma)")
    n_loc_samples: int = _f(25, lo=1, hi=100000, doc="N_x localization samples (With Uncertainty)")


@dataclass(frozen=True)
class SensitivityConfig:
    sigmas_m: tuple[float, ...] = _f(factory=lambda: (0.05, 0.1, 0.2, 0.3, 0.5), lo=0.0, hi=10.0)
    realizations: int = _f(100, lo=1, hi=1000000)
    n_loc_samples: int = _f(50, lo=1, hi=100000)


@dataclass(frozen=True)
class BiasMapsConfig:
    extent_m: float = _f(0.6, lo=0.01, hi=10.0, doc="bias grid spans [-extent, extent] in x and y")
    steps: int = _f(25, lo=3, hi=401)


@dataclass(frozen=True)
class DirichletEvalConfig:
    n_ss: int = _f(100, lo=1, hi=1000000, doc="N_ss: posterior-cloud points kept after each step (Dirichlet method)")


@dataclass(frozen=True)
class EvaluateConfig:
    targets: tuple[str, ...] = _f("all", words=("all",),
                                  doc="'all' = every modelled instance present in the scanned AVD features, "
                                      "or a list of instance names")
    n_candidates: int = _f(4, lo=2, hi=1000, doc="candidate classes per target, the target included")
    candidates: tuple[str, ...] = _f("sampled", words=("sampled", "all"),
                                     doc="'sampled' = the target + n_candidates - 1 others drawn per target; "
                                         "'all' = every modelled class; or a list of the other candidates")
    candidate_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="seeds the per-target candidate draw")
    tracks_per_target: int = _f(8, lo=1, hi=1000, doc="distinct tracks per target")
    track_images: tuple[str, ...] = _f(factory=tuple, doc="explicit track (one target only); empty = build tracks")
    track_length: int = _f(9, lo=2, hi=200)
    max_difficulty: int = _f(4, lo=1, hi=5)
    max_ray_residual_m: float = _f(0.25, lo=1e-3, hi=100.0,
                                   doc="an instance whose rays through its box centres lie farther than this (RMS, "
                                       "metres) from their least-squares point is excluded from that scan, its "
                                       "residual named (a duplicated or moved object; real scans: at most 8 cm when "
                                       "consistent, 2.6-3.2 m for the duplicated ones)")
    yaw_source: str = _f("truth", choices=("truth", "config"))
    yaw_deg: float = _f(0.0, lo=-360.0, hi=360.0, doc="yaw_source = 'config' with a single target")
    yaws_deg: tuple[float, ...] = _f(factory=tuple, lo=-360.0, hi=360.0,
                                     doc="yaw_source = 'config': one yaw per entry of 'targets'")
    variance_floor: float = _f(1e-6, lo=0.0, hi=1.0)
    experiments: tuple[str, ...] = _f(
        factory=lambda: ("gp_models", "biased", "randomized", "sensitivity", "bias_maps"))
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    bootstrap: int = _f(2000, lo=100, hi=1000000, doc="bootstrap resamples for every 95 % confidence interval")
    ablations: tuple[str, ...] = _f(factory=lambda: ("evaluate.test_domain_variance=cross_fit",),
                                    doc="'models.KEY=VALUE' or 'evaluate.test_domain_variance=VALUE' variants "
                                        "evaluated on the same population (models KEY: component_rule, "
                                        "noise_floor, n_components, informative_min)")
    test_domain_variance: str = _f("none", choices=("none", "cross_fit"),
                                   doc="likelihood of the GP-based methods: none = the paper's (GP predictive "
                                       "alone); cross_fit = plus a test-domain variance per score component, "
                                       "ML-estimated on labelled AVD crops of the other scans (one scan: of the "
                                       "other instances), never the evaluated cell's own")
    confident_threshold: float = _f(0.99, lo=0.5, hi=1.0,
                                    doc="a confident error: max P >= this on a wrong class")
    attribution: bool = _f(True, doc="also evaluate With Uncertainty with poses only (dropout samples -> their "
                                     "mean) and with dropout only (no pose sampling), on the same population")
    biased: BiasedConfig = _f(factory=BiasedConfig)
    randomized: RandomizedConfig = _f(factory=RandomizedConfig)
    sensitivity: SensitivityConfig = _f(factory=SensitivityConfig)
    bias_maps: BiasMapsConfig = _f(factory=BiasMapsConfig)
    dirichlet: DirichletEvalConfig = _f(factory=DirichletEvalConfig)


@dataclass(frozen=True)
class ReportConfig:
    title: str = _f("viewfuse report")
    dpi: int = _f(110, lo=30, hi=600)


# Simulation class models (paper §5.3): hand-specified score vectors per view angle, one row of
# three (class-1, class-2, class-3 scores) per angle, flattened angle-major. Class 2 (the truth)
# has the "inverse" view at 260-280° (seen from the south it looks like class 1); class 3, nearly
# ambiguous with class 2 elsewhere, has the same look 20° further west (an aliased view).
_SIM_ANGLES = (0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0, 220.0, 240.0,
               260.0, 280.0, 300.0, 320.0, 340.0)
_SIM_SCORES_1 = (
    0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20,
    0.60, 0.20, 0.20, 0.50, 0.20, 0.30, 0.45, 0.15, 0.40, 0.45, 0.15, 0.40, 0.50, 0.20, 0.30, 0.60, 0.20, 0.20,
    0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20,
)
_SIM_SCORES_2 = (
    0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35,
    0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35,
    0.20, 0.45, 0.35, 0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35, 0.20, 0.45, 0.35,
)
_SIM_SCORES_3 = (
    0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45,
    0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45,
    0.60, 0.20, 0.20, 0.60, 0.20, 0.20, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45, 0.20, 0.35, 0.45,
)


@dataclass(frozen=True)
class SimulateConfig:
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    realizations: int = _f(300, lo=1, hi=1000000)
    scenarios: tuple[str, ...] = _f(factory=lambda: ("model_uncertainty", "localization_bias"),
                                    choices=("model_uncertainty", "localization_bias"),
                                    doc="which scenarios to run")
    class_names: tuple[str, ...] = _f(factory=lambda: ("class 1", "class 2", "class 3"),
                                      doc="display names of the three classes")
    truth_class: int = _f(2, lo=1, hi=3, doc="ground-truth class, 1-based")
    view_angles_deg: tuple[float, ...] = _f(factory=lambda: _SIM_ANGLES, lo=-360.0, hi=360.0,
                                            doc="bearings (from the object, CCW from east) of the model points")
    view_radii: tuple[float, ...] = _f(factory=lambda: (20.0, 35.0), lo=0.0, hi=1e6,
                                       doc="model points = every angle at every radius, same scores")
    scores_class1: tuple[float, ...] = _f(factory=lambda: _SIM_SCORES_1, lo=0.0, hi=1.0,
                                          doc="class 1's score vector (3 values) per angle, flattened")
    scores_class2: tuple[float, ...] = _f(factory=lambda: _SIM_SCORES_2, lo=0.0, hi=1.0)
    scores_class3: tuple[float, ...] = _f(factory=lambda: _SIM_SCORES_3, lo=0.0, hi=1.0)
    track_start: tuple[float, ...] = _f(factory=lambda: (-30.0, -20.0), lo=-1e6, hi=1e6,
                                        doc="first robot position (x east, y north), object at origin")
    track_length: float = _f(60.0, lo=1e-3, hi=1e6, doc="track length, eastward")
    track_steps: int = _f(21, lo=2, hi=500, doc="K poses along the track, evenly spaced")
    sigma_max: float = _f(0.3, lo=0.0, hi=10.0, doc="model-uncertainty level: sigma_u^2 ~ U(0, sigma_max^2)")
    n_samples: int = _f(20, lo=1, hi=10000, doc="N_s measurement samples per step")
    bias_east: float = _f(-8.0, lo=-1e6, hi=1e6, doc="localization bias on every pose estimate, easting")
    sigma_loc: float = _f(16.0, lo=0.0, hi=1e6, doc="pose std told to Model with Uncertainty under bias")
    n_loc_samples: int = _f(100, lo=1, hi=100000, doc="N_x localization samples under bias")
    variance_floor: float = _f(1e-6, lo=0.0, hi=1.0, doc="floor on past samples' variance (ours)")
    simple_bayes_floor: float = _f(1e-3, lo=1e-12, hi=0.3,
                                   doc="Simple Bayes clips scores to >= this, then normalises")
    restarts: int = _f(3, lo=0, hi=100, doc="GP optimizer restarts")
    # Tight-ish bounds keep the three classes' models about equally confident: exact hand-made
    # responses would otherwise fit near-zero variance for flat classes, and the widest model would
    # win every noisy measurement for that reason alone.
    amplitude_bounds: tuple[float, ...] = _f(factory=lambda: (0.005, 0.05), lo=1e-12, hi=1e6)
    length_scale_bounds: tuple[float, ...] = _f(factory=lambda: (5.0, 30.0), lo=1e-3, hi=1e6)
    noise_bounds: tuple[float, ...] = _f(factory=lambda: (0.005, 0.02), lo=1e-12, hi=1e3,
                                         doc="white noise: the classifier's jitter at a fixed view")
    example_realization: int = _f(0, lo=0, hi=1000000, doc="realization drawn in the measurement figures")
    chunk: int = _f(25, lo=1, hi=100000, doc="realizations fused per batch (memory vs speed)")
    dpi: int = _f(110, lo=30, hi=600, doc="PNG resolution of the simulation report")
    # The paper's §5.3 claims and the model-confidence regime sweep (pipeline/evaluation/claims.py,
    # pipeline/evaluation/sweep.py).
    model_confidence: str = _f("fitted", choices=("fitted", "hand_made"),
                               doc="fitted: GP noise fitted within noise_bounds; hand_made: every GP's "
                                   "noise variance set to hand_made_noise after the fit")
    hand_made_noise: float = _f(1e-4, lo=1e-12, hi=1.0, doc="GP noise variance when model_confidence = hand_made")
    claim_step: int = _f(15, lo=0, hi=499, doc="the paper's 'step 15' (0-based track step) of the claims")
    confident_threshold: float = _f(0.99, lo=0.5, hi=1.0,
                                    doc="confident error: max P >= this on a wrong class (as evaluate)")
    sweep: str = _f("small", choices=("off", "small", "full"), doc="regime sweep over GP noise x sigma_max")
    sweep_noise: tuple[float, ...] = _f(factory=lambda: (1e-5, 1e-4, 1e-3, 5e-3, 2e-2), lo=1e-12, hi=1.0,
                                        doc="small sweep: GP noise variances")
    sweep_sigma_max: tuple[float, ...] = _f(factory=lambda: (0.1, 0.3, 0.5, 0.7, 1.0), lo=0.0, hi=10.0,
                                            doc="small sweep: sigma_max values")
    sweep_realizations: int = _f(100, lo=2, hi=100000, doc="small sweep: realizations per grid point")
    sweep_full_noise: tuple[float, ...] = _f(
        factory=lambda: (1e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2), lo=1e-12, hi=1.0,
        doc="full sweep: GP noise variances")
    sweep_full_sigma_max: tuple[float, ...] = _f(
        factory=lambda: (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 1.5), lo=0.0, hi=10.0,
        doc="full sweep: sigma_max values")
    sweep_full_realizations: int = _f(300, lo=2, hi=100000, doc="full sweep: realizations per grid point")


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
    report: ReportConfig = _f(factory=ReportConfig)
    simulate: SimulateConfig = _f(factory=SimulateConfig)
    study: StudyConfig = _f(factory=StudyConfig)
    # Where the config file lives; relative paths in it resolve against its project root.
    source_path: str = field(default="", compare=False, metadata={"internal": True})

    # -- derived locations -------------------------------------------------------------------
    @property
    def root(self) -> Path:
        """Project root: the parent of ``configs/`` for files there, else the file's folder."""
        if not self.source_path:
            return Path.cwd()
        p = Path(self.source_path).resolve().parent
        return p.parent if p.name == "configs" else p

    def resolve(self, path: str) -> Path:
        p = Path(path).expanduser()
        return p if p.is_absolute() else self.root / p

    @property
    def artifacts_dir(self) -> Path:
        """The artifacts root, absolute and normalised (``..`` folded away)."""
        return Path(os.path.abspath(self.resolve(self.run.artifacts)))

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
        return hashlib.sha256(canonical_json(to_dict(self.section(name))).encode()).hexdigest()


# ----------------------------------------------------------------------------------------------
def to_dict(obj: Any) -> Any:
    """Plain (JSON-able) form of a config or section."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not f.metadata.get("internal")}
    if isinstance(obj, (tuple, list)):
        return [to_dict(v) for v in obj]
    return obj


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)




ABLATION_KEYS = ("models.component_rule", "models.noise_floor", "models.n_components", "models.informative_min",
                 "evaluate.test_domain_variance")
TEST_DOMAIN_MODES = ("none", "cross_fit")


def is_model_ablation(ablation: str) -> bool:
    """An ablation that needs its own model bank (a ``models.*`` override)."""
    return ablation.split("=", 1)[0].strip().startswith("models.")


def test_domain_mode(cfg: "Config", ablation: str | None) -> str:
    """``evaluate.test_domain_variance`` of the default run (None) or of one ablation variant."""
    if ablation is not None and "=" in ablation:
        key, raw = (t.strip() for t in ablation.split("=", 1))
        if key == "evaluate.test_domain_variance":
            value = raw.strip("'\"")
            if value not in TEST_DOMAIN_MODES:
                raise ConfigError(f"evaluate.ablations: {ablation!r}: the value must be none or cross_fit")
            return value
    return cfg.evaluate.test_domain_variance
