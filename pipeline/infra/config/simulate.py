"""The ``[simulate]`` section: the paper's section 5.3 scenarios and the regime sweep."""
from __future__ import annotations

from dataclasses import dataclass

from pipeline.infra.config.fields import SEED_MAX, setting as _f


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
    # The paper's §5.3 claims and the model-confidence regime sweep (pipeline/evaluation/simulation/claims.py,
    # pipeline/evaluation/simulation/sweep.py).
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
