"""The sections of the evaluation protocol and its report: ``[evaluate]`` (targets, candidates,
localization settings, statistics, ablations, the test domain) and ``[report]``."""
from __future__ import annotations

from dataclasses import dataclass

from pipeline.infra.config.fields import SEED_MAX, setting as _f
from pipeline.infra.config.learning import SCORE_SPACES
from pipeline.infra.config.own import Extendable, Own, own_field


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
class BiasedRandomizedConfig:
    """The paper's §5.5 setting: one bias on every pose, then per-axis Gaussian noise around the biased
    estimate, With Uncertainty told the same sigma."""
    bias_m: tuple[float, ...] = _f(factory=lambda: (-0.30, 0.20), lo=-100.0, hi=100.0,
                                   doc="[x, y] metres: the bias on every pose (the paper does not state its size)")
    sigma_m: float = _f(0.30, lo=0.0, hi=10.0, doc="per-axis std around the biased estimate, and the std told "
                                                   "to With Uncertainty (the paper: 30 cm)")
    realizations: int = _f(20, lo=1, hi=1000000, doc="realizations per (target, track)")
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
class StatisticsConfig:
    cluster: str = _f("target", choices=("target", "scan", "category", "crossed"),
                      doc="the design's independent unit, the top level of every pooled CI: target = targets, "
                          "then tracks; scan = scans, then the targets of each scan, then tracks; category = "
                          "categories, then their targets, then tracks (category classes: data.real_imagery."
                          "dataset = 'eth80'); crossed = targets and scans resampled independently, each (target, "
                          "scan) cell's tracks weighted by the product of the two multiplicities (the same objects "
                          "recur across scans: configs/real_full.toml)")


@dataclass(frozen=True)
class PrimaryConfig:
    """The one primary comparison, declared before the run: its verdict is read at its own 95 % (no
    multiplicity adjustment: it is the only one declared); every other result is exploratory."""
    metric: str = _f("confident_error_final", doc="a metric key of pipeline/evaluation/metrics/spec.py")
    methods: tuple[str, ...] = _f(factory=lambda: ("with_uncertainty", "model_based"),
                                  doc="[method, baseline]: two registered method keys, the difference is method - "
                                      "baseline")
    setting: str = _f("all", doc="'all' = pooled over every localization setting of the run; or one experiment "
                                 "with one setting: 'biased', 'biased_randomized', 'randomized' (one sigma only)")


# Defaults that code outside the section reads too (the simulate stage's ECE, a summary that lacks
# them): module constants, so they stay in the stage keys' code hash; a setting's own default is in
# the keys only as the resolved value of the sections a stage declares (stages/framework/declarations.py).
BOOTSTRAP = 2000
CONFIDENT_THRESHOLD = 0.99
ECE_BINS = 15


def cluster_of(ev) -> str:
    """The clustering in force: ``evaluate.statistics.cluster``, or "scan" where only the former
    key ``evaluate.resample_scans`` asks for it."""
    c = getattr(getattr(ev, "statistics", None), "cluster", "target")   # a hand-built section may lack it
    return "scan" if getattr(ev, "resample_scans", False) and c == "target" else c


@dataclass(frozen=True)
class EvaluateConfig(Extendable):
    targets: tuple[str, ...] = _f("all", words=("all",),
                                  doc="'all' = every modelled instance present in the scanned AVD features, "
                                      "or a list of instance names")
    n_candidates: int = _f(4, lo=2, hi=1000, doc="candidate classes per target, the target included")
    candidates: tuple[str, ...] = _f("sampled", words=("sampled", "all", "hard"),
                                     doc="'sampled' = the target + n_candidates - 1 others drawn per target; "
                                         "'hard' = the target + the n_candidates - 1 classes nearest it in score "
                                         "space (Euclidean between class mean deterministic score vectors over "
                                         "the training views; ties by name); 'all' = every modelled class; or a "
                                         "list of the other candidates")
    candidate_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="seeds the per-target candidate draw")
    candidate_folds: bool = _f(False, doc="candidates come from the target's own fold only: a class named "
                                          "'<name>__f<k>' is in fold k (category classes, data.real_imagery.dataset "
                                          "= 'eth80')")
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
    bootstrap: int = _f(BOOTSTRAP, lo=100, hi=1000000, doc="bootstrap resamples for every 95 % confidence interval")
    resample_scans: bool = _f(False, doc="the former spelling of statistics.cluster = 'scan': the population's CIs "
                                         "resample scans, then targets within each scan, then tracks (pooled: the "
                                         "mean over scans of each scan's pool over its targets)")
    statistics: StatisticsConfig = _f(factory=StatisticsConfig)
    ablations: tuple[str, ...] = _f(factory=lambda: ("evaluate.test_domain_variance=cross_fit",),
                                    doc="'models.KEY=VALUE' or 'evaluate.test_domain_variance=VALUE' variants "
                                        "evaluated on the same population (models KEY: component_rule, "
                                        "noise_floor, n_components, informative_min, score_space)")
    fit_spaces: tuple[str, ...] = _f(factory=tuple, choices=SCORE_SPACES,
                                     doc="score spaces whose model bank is fitted only for the test-domain fit "
                                         "table (95 % coverage per space and likelihood): the models stage fits "
                                         "each one's bank, the evaluate stage fits it to the labelled crops and "
                                         "runs no cell on it; the run's own space and a space an ablation "
                                         "already fits are not fitted again")
    test_domain_variance: str = _f("none", choices=("none", "cross_fit"),
                                   doc="likelihood of the GP-based methods: none = the paper's (GP predictive "
                                       "alone); cross_fit = plus a test-domain variance per score component, "
                                       "ML-estimated on labelled AVD crops of the other scans (one scan: of the "
                                       "other instances), never the evaluated cell's own")
    likelihood_tail: str = _f("none", choices=("none", "student_t"),
                              doc="student_t: also run with_uncertainty_t and model_based_t, each step's predictive "
                                  "a Student-t whose degrees of freedom are ML-fitted per fold on the standardized "
                                  "residuals of the other folds' labelled crops (as test_domain_variance's folds; "
                                  "pipeline/evaluation/domain/tails.py); none: they do not run")
    confident_threshold: float = _f(CONFIDENT_THRESHOLD, lo=0.5, hi=1.0,
                                    doc="a confident error: max P >= this on a wrong class")
    ece_bins: int = _f(ECE_BINS, lo=2, hi=1000, doc="equal-width confidence bins of the top-label ECE and the reliability "
                                              "diagram")
    primary_metrics: tuple[str, ...] = _f(factory=lambda: ("correct_final", "confident_error_final"),
                                          doc="the metrics the verdict's bottom line speaks of (keys of "
                                              "pipeline/evaluation/metrics/spec.py); every other is exploratory")
    primary: PrimaryConfig = _f(factory=PrimaryConfig)
    attribution: bool = _f(True, doc="also evaluate With Uncertainty with poses only (dropout samples -> their "
                                     "mean) and with dropout only (no pose sampling), on the same population")
    biased: BiasedConfig = _f(factory=BiasedConfig)
    randomized: RandomizedConfig = _f(factory=RandomizedConfig)
    biased_randomized: BiasedRandomizedConfig = _f(factory=BiasedRandomizedConfig)
    sensitivity: SensitivityConfig = _f(factory=SensitivityConfig)
    bias_maps: BiasMapsConfig = _f(factory=BiasMapsConfig)
    # [evaluate.<key>] of a method's model provider (pipeline/method/provider.py): config/own.py
    own: Own = own_field("evaluate")


@dataclass(frozen=True)
class ReportConfig:
    title: str = _f("viewfuse report")
    dpi: int = _f(110, lo=30, hi=600)
    strict: str = _f("contradictions", choices=("contradictions", "all"),
                     doc="which self-check failures stop the build: contradictions = a label its CI "
                         "contradicts, two numbers for one statistic, a value outside its CI, a caption "
                         "without a finding (layout slips: the page is written, the figure carries a "
                         "warning box); all = layout slips too (tests and CI)")
    equivalence_margin_correct: float = _f(0.05, lo=0.0, hi=1.0, doc="the paper's 'similar' correct ratios: the "
                                           "scorecard's claim holds when the 95 % CI of the paired difference "
                                           "lies within ± this")




ABLATION_KEYS = ("models.component_rule", "models.noise_floor", "models.n_components", "models.informative_min",
                 "models.score_space", "evaluate.test_domain_variance")
TEST_DOMAIN_MODES = ("none", "cross_fit")


def fit_only_banks(cfg) -> tuple[str, ...]:
    """The ``models.score_space=<space>`` bank of each ``evaluate.fit_spaces`` entry that no other
    bank of the run holds (not the run's own space, not a ``models.score_space`` ablation's): named
    like an ablation, fitted by the models stage, read by the test-domain fit only."""
    ev = cfg.evaluate
    have = {cfg.models.score_space} | {a.split("=", 1)[1].strip().strip("'\"") for a in ev.ablations
                                       if a.split("=", 1)[0].strip() == "models.score_space" and "=" in a}
    return tuple(f"models.score_space={s}" for s in ev.fit_spaces if s not in have)


def is_model_ablation(ablation: str) -> bool:
    """An ablation that needs its own model bank (a ``models.*`` override)."""
    return ablation.split("=", 1)[0].strip().startswith("models.")

