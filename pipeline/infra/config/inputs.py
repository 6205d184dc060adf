"""The sections that say what a run is and what it reads: ``[run]`` and ``[data]`` (synthetic
stand-ins or real dataset roots)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pipeline.infra.config.fields import SEED_MAX, setting as _f
from pipeline.infra.config.own import Extendable, Own, own_field


# The real AVD instance map (docs/formats/avd_instance_id_map.txt): its names in id order (the
# line number is the id). The synthetic stand-ins may only use these names (checked at load), and
# loaders.synthetic.objects writes the map from this tuple.
AVD_INSTANCES = (
    "background",
    "advil_liqui_gels",
    "aunt_jemima_original_syrup",
    "bumblebee_albacore",
    "cholula_chipotle_hot_sauce",
    "coca_cola_glass_bottle",
    "crest_complete_minty_fresh",
    "crystal_hot_sauce",
    "expo_marker_red",
    "hersheys_bar",
    "honey_bunches_of_oats_honey_roasted",
    "honey_bunches_of_oats_with_almonds",
    "hunts_sauce",
    "listerine_green",
    "mahatma_rice",
    "nature_valley_granola_thins_dark_chocolate",
    "nutrigrain_harvest_blueberry_bliss",
    "pepto_bismol",
    "pringles_bbq",
    "progresso_new_england_clam_chowder",
    "quaker_chewy_low_fat_chocolate_chunk",
    "red_bull",
    "softsoap_clear",
    "softsoap_gold",
    "softsoap_white",
    "spongebob_squarepants_fruit_snaks",
    "tapatio_hot_sauce",
    "vo5_tea_therapy_healthful_green_tea_smoothing_shampoo",
    "nature_valley_sweet_and_salty_nut_almond",
    "nature_valley_sweet_and_salty_nut_cashew",
    "nature_valley_sweet_and_salty_nut_peanut",
    "nature_valley_sweet_and_salty_nut_roasted_mix_nut",
    "paper_plate",
    "red_cup",
)

# The real AVD instance names used by the synthetic stand-ins (all are BigBIRD folder names; the
# same list and order as loaders.synthetic.objects.DEFAULT_OBJECTS, whose test checks they agree).
DEFAULT_INSTANCES = (
    "aunt_jemima_original_syrup",
    "cholula_chipotle_hot_sauce",
    "crystal_hot_sauce",
    "honey_bunches_of_oats_honey_roasted",
    "honey_bunches_of_oats_with_almonds",
    "mahatma_rice",
    "pepto_bismol",
    "tapatio_hot_sauce",
    "coca_cola_glass_bottle",
    "pringles_bbq",
    "listerine_green",
    "red_bull",
)


@dataclass(frozen=True)
class RunConfig:
    name: str = _f("synthetic", doc="run name; outputs go to <artifacts>/<name>/<stage>/")
    artifacts: str = _f("artifacts", doc="artifacts root, relative to the config's project root")
    device: str = _f("auto", choices=("auto", "cpu", "cuda"))
    threads: int = _f(0, lo=0, hi=256, doc="torch/BLAS threads; 0 = number of cores")
    executor: str = _f("local", choices=("local", "ray"),
                       doc="where the features and evaluate stages run their tasks: local = this "
                           "process; ray = Ray tasks (pip install -e '.[ray]'); outputs are the same")
    ray_address: str = _f("", doc="executor ray: empty = start a local Ray instance (loopback only); "
                                  "'auto' or 'ray://host:port' = join that cluster")
    ray_workers: int = _f(0, lo=0, hi=4096, doc="executor ray, local instance: CPUs it gets; 0 = all cores")
    memory_gb: float = _f(0.0, lo=0.0, hi=1e6,
                          doc="memory budget, GiB: settings whose peak would exceed it are refused before the work "
                              "starts, and batch sizes and worker counts are capped to fit; 0 = 80 % of what this "
                              "process may use (physical memory, the cgroup limit, the address space ulimit -v "
                              "leaves: the lowest); a value above that is lowered to it, with a warning")
    max_bootstrap_minutes: float = _f(60.0, lo=0.0, hi=1e6,
                                      doc="evaluate refuses, before its grid, an evaluate.bootstrap whose intervals it "
                                          "estimates (a timed small draw, scaled) to take longer than this; 0 = no "
                                          "limit (the estimate is still said). Not part of any stage's key")
    stage_cache_gb: float = _f(20.0, lo=0.0, hi=1e6,
                               doc="the stage cache shared across run names (<artifacts>/.stage-cache/): a stage "
                                   "whose key matches one any run finished reuses its outputs (hard links, "
                                   "verified by sha256); at most this many GiB, least recently used entries "
                                   "removed first; 0 = off. Not part of any stage's key")
    stage_cache: str = _f("", doc="the stage cache's folder; empty = <artifacts>/.stage-cache. A relative path "
                                  "resolves against the config's project root. The seed study points every seed's "
                                  "chain at its run's cache. Not part of any stage's key")
    method_seconds: float = _f(600.0, lo=0.0, hi=1e6,
                               doc="a fusion method's call on one track still running after this many seconds is "
                                   "stopped and named (evaluate's cells and planning, local executor); 0 = no "
                                   "limit. Not part of any stage's key")
    max_minutes: float = _f(120.0, lo=0.0, hi=1e6,
                            doc="a stage whose estimate (pipeline/infra/cost.py: every setting that multiplies its "
                                "work, per-unit seconds measured on a 2-core machine) is longer than this is refused "
                                "before it starts, naming the keys; 0 = no limit. Not part of any stage's key")


@dataclass(frozen=True)
class SyntheticDataConfig:
    instances: tuple[str, ...] = _f(factory=lambda: DEFAULT_INSTANCES)
    instances_per_scan: int = _f(9, lo=0, hi=1000,
                                 doc="instances placed in each AVD scan: scan k of S takes this many "
                                     "consecutive instances (cyclically) starting at round(k * n / S); "
                                     "0 = all in every scan")
    bigbird_cameras: tuple[int, ...] = _f(factory=lambda: (1,), lo=1, hi=5)
    angle_step_deg: int = _f(3, lo=3, hi=120, doc="turntable step; a multiple of 3 as in BigBIRD")
    bigbird_width: int = _f(1280, lo=64, hi=4096)
    bigbird_height: int = _f(1024, lo=64, hi=4096)
    write_depth: bool = _f(False)
    # BigBIRD rig nuisance (per view unless said otherwise); 0 switches each one off.
    bigbird_read_noise: float = _f(1.5, lo=0.0, hi=50.0,
                                   doc="sensor read noise std, grey levels (Carmine-class CMOS)")
    bigbird_shot_noise: float = _f(0.04, lo=0.0, hi=10.0,
                                   doc="shot noise: variance grows by this many grey levels^2 per grey level")
    bigbird_exposure_jitter: float = _f(0.04, lo=0.0, hi=0.5, doc="per-view exposure gain std (fraction)")
    bigbird_wb_jitter: float = _f(0.02, lo=0.0, hi=0.5, doc="per-view white-balance gain std per channel")
    bigbird_decentre_mm: float = _f(6.0, lo=0.0, hi=50.0,
                                    doc="object placed this far off the turntable axis (per object, "
                                        "random direction), so it orbits as the table turns")
    bigbird_wobble_deg: float = _f(0.8, lo=0.0, hi=10.0, doc="per-view yaw wobble std of the object")
    bigbird_wobble_mm: float = _f(1.0, lo=0.0, hi=20.0, doc="per-view position wobble std of the object")
    bigbird_mask_error_px: int = _f(2, lo=0, hi=10,
                                    doc="mask boundary moved in or out by up to this many pixels per view, "
                                        "plus ragged edge pixels")
    bigbird_jpeg_quality: int = _f(75, lo=50, hi=100, doc="BigBIRD JPEG quality (an estimate of the rig's)")
    avd_width: int = _f(640, lo=64, hi=1920)
    avd_height: int = _f(360, lo=36, hi=1080)
    grid_step_m: float = _f(0.3, lo=0.05, hi=2.0)
    room_size_m: tuple[float, ...] = _f(factory=lambda: (3.6, 3.0), lo=0.5, hi=100.0)
    distractors: int = _f(6, lo=0, hi=100, doc="clutter boxes in the AVD room")
    occluders: int = _f(4, lo=0, hi=100,
                        doc="small clutter items put right beside instances, so some views see them "
                            "partly occluded")
    interpolated_fraction: float = _f(0.25, lo=0.0, hi=0.9,
                                      doc="share of AVD images left unregistered (empty R, t)")
    jpeg_quality: int = _f(88, lo=50, hi=100, doc="AVD JPEG quality")
    avd_camera_height_m: float = _f(0.95, lo=0.2, hi=2.0, doc="AVD camera height above the floor")
    avd_pitch_deg: float = _f(10.0, lo=0.0, hi=30.0, doc="AVD camera pitch below the horizon")
    # AVD capture nuisance.
    avd_auto_exposure: float = _f(0.6, lo=0.0, hi=1.0,
                                  doc="auto-exposure strength: each image's gain moves its mean "
                                      "brightness this far (fraction) towards mid-grey, plus 4 % jitter")
    avd_motion_blur_fraction: float = _f(0.08, lo=0.0, hi=1.0, doc="share of AVD images with motion blur")
    avd_motion_blur_px: int = _f(7, lo=1, hi=51, doc="longest motion-blur streak, pixels")
    avd_box_jitter_px: int = _f(3, lo=0, hi=50, doc="annotation box sides moved by up to this many pixels")
    workers: int = _f(2, lo=1, hi=64, doc="processes rendering views; the files do not depend on it")


@dataclass(frozen=True)
class RealImageryConfig:
    """data.source = "real_imagery": COIL-100 photographs on real AVD geometry (loaders/real_imagery/,
    docs/real_data.md). The COIL folder is ``data.coil_root``, the AVD root ``data.avd_root``."""
    objects: tuple[int, ...] = _f(factory=lambda: tuple(range(2, 22)), lo=1, hi=100,
                                  doc="COIL-100 object numbers used as classes (coil_obj<k>); each located AVD "
                                      "instance stands for one of them (seeded pairing)")
    train_step_deg: int = _f(10, lo=10, hi=180, doc="training views every this many degrees (a multiple of 5 "
                                                    "dividing 360); the other 5-degree views are held out for the frames")
    pairing_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="which COIL object each located AVD instance stands for")
    yaws_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="each paired object's yaw, uniform on [0, 360) degrees")
    max_difficulty: int = _f(4, lo=1, hi=5, doc="AVD boxes up to this difficulty locate instances and get frames")
    max_ray_residual_m: float = _f(0.25, lo=0.0, hi=100.0,
                                   doc="an instance whose rays miss their point by more (RMS, m) is not paired")
    frames: str = _f("viewpoints", choices=("viewpoints", "all"),
                     doc="which AVD views of a paired instance get a frame: 'viewpoints' = per grid point the view "
                         "facing it best (the only views a track can take); 'all' = every box")
    max_view_error_deg: float = _f(10.0, lo=0.0, hi=180.0,
                                   doc="a frame shows the held-out COIL view nearest its bearing; a view further "
                                       "than this from the bearing gives no frame (counted in truth.json)")
    noise_std: float = _f(2.0, lo=0.0, hi=50.0, doc="sensor model: Gaussian read noise std, grey levels")
    blur_sigma_px: float = _f(0.7, lo=0.0, hi=10.0, doc="sensor model: Gaussian optical blur sigma, pixels (0 = none)")
    jpeg_quality: int = _f(85, lo=30, hi=100, doc="sensor model: JPEG quality of the written AVD frames")
    train_jpeg_quality: int = _f(95, lo=30, hi=100, doc="JPEG quality of the training views (BigBIRD stores JPEG)")
    # Category-level classes (dataset = "eth80", loaders/real_imagery/category.py, docs/real_data.md).
    dataset: str = _f("coil", choices=("coil", "eth80"),
                      doc="coil = one COIL-100 object per class (data.coil_root); eth80 = one ETH-80 category per "
                          "class, folds by instance, every scored photograph of an unseen instance (data.eth80_root)")
    categories: tuple[str, ...] = _f(factory=lambda: ("apple", "car", "cow", "cup", "dog", "horse", "pear", "tomato"),
                                     doc="eth80: the categories (classes)")
    instances: tuple[int, ...] = _f(factory=lambda: tuple(range(1, 10)), lo=1, hi=1000,
                                    doc="eth80: the instance numbers; fold f holds out instance f of every category")
    elevations: tuple[int, ...] = _f(factory=lambda: (90,), lo=0, hi=999,
                                     doc="eth80: the rings read (the name's elevation field; 090 = equatorial)")
    background: str = _f("black", choices=("black", "avd_frames"),
                         doc="the frames' surround, on both sides (training views too, unless train_background "
                             "says otherwise): the object cut out by its mask (COIL) or map (ETH-80) onto black "
                             "(the control), or over a region of a real AVD frame (data.avd_frames_root: real "
                             "clutter, the real configs' setting)")
    train_pad: str = _f("surround", choices=("surround", "none"),
                        doc="'surround' = every training photograph is extended with the frames' surround "
                            "(black or its clutter) until no crop the features stage takes runs off it, so no "
                            "pad value (features.pad) reaches a training crop; 'none' = the photograph as it is "
                            "(crops running off it are padded by features.pad, the runs before this key)")
    train_background: str = _f("same", choices=("same", "original", "black", "avd_frames"),
                               doc="the training views' background: 'same' = data.real_imagery.background (the "
                                   "controlled default); 'original' = the photograph's own (ETH-80's blue cloth); "
                                   "'black' | 'avd_frames' = that kind, a deliberate mismatch with the frames")
    class_level: str = _f("category", choices=("category", "instance"),
                          doc="eth80: what a class model of fold f is fitted on: 'category' = the category's OTHER "
                              "instances; 'instance' = instance f itself (its training azimuths; needs "
                              "view_split = 'alternate'). The frames do not depend on it: the controlled contrast")
    contrast: bool = _f(False, doc="eth80: also the instance arm in the same run (class_level = 'category' is the "
                                   "first): the models stage fits an instance-level bank beside the category one, "
                                   "evaluate runs both on the same tracks, the report pairs them (needs view_split "
                                   "= 'alternate'; configs/real_contrast.toml)")
    view_split: str = _f("none", choices=("none", "alternate"),
                         doc="eth80: which azimuths train and which the frames show: 'none' = every azimuth both; "
                             "'alternate' = training on 0, 45, ..., 315, frames on 22.5, 67.5, ... (held out, "
                             "as COIL's 5-degree views)")
    background_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="background = avd_frames: which frame and region")
    workers: int = _f(2, lo=1, hi=64, doc="processes writing the scans' frames, a scan each; the files do not depend on it")


@dataclass(frozen=True)
class DataConfig(Extendable):
    source: str = _f("synthetic",
                     doc="a registered dataset source (pipeline/infra/datasets.py): synthetic stand-ins | real "
                         "BigBIRD + AVD roots | real_imagery: COIL-100 photographs on real AVD scans' geometry "
                         "(docs/real_data.md) | one of your own (docs/extending.md), with its [data.<name>] section")
    coil_root: str = _f("", doc="real_imagery: folder of COIL-100 obj<k>__<deg>.png files")
    eth80_root: str = _f("", doc="real_imagery, dataset eth80: ETH-80 root (<category><n>/ instance folders)")
    avd_frames_root: str = _f("", doc="real_imagery, background avd_frames: folder of real AVD frames (*.png, *.jpg)")
    bigbird_root: str = _f("", doc="real data: folder holding BigBIRD object folders")
    avd_root: str = _f("", doc="real data: AVD root holding instance_id_map.txt and scan folders")
    scans: tuple[str, ...] = _f(factory=lambda: ("Home_001_1", "Home_002_1"),
                                doc="AVD scan folders; every one is scored (features) and evaluated")
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    skip_bad_views: bool = _f(True, doc="every stage reading the data counts, logs and skips bad entries "
                                         "(images, boxes, poses) in its manifest; false = the first one stops the stage")
    max_image_megapixels: float = _f(64.0, lo=0.01, hi=10000.0,
                                     doc="images whose header declares more pixels are bad entries, not decoded "
                                         "(real BigBIRD views are 1.3 MP, AVD images 2.1 MP)")
    synthetic: SyntheticDataConfig = _f(factory=SyntheticDataConfig)
    real_imagery: RealImageryConfig = _f(factory=RealImageryConfig)
    # The [data.<source>] section of a source that declares one (its own dataclass, built at load
    # like the methods' sections: config/own.py); to_dict writes it, so the data section's hash
    # and the recorded config hold it.
    own: Own = own_field("data")

    @property
    def options(self) -> Any:
        """The section of the source ``source`` names (None: it declares none)."""
        return self.own.built(self.source)
