"""Peak-memory estimates (bytes) of the steps whose memory grows with a setting, from the arrays
each step holds; ``pipeline.infra.budget`` checks them against ``run.memory_gb``. Pure formulas of
config values, so a refusal costs nothing. Each is an upper bound within a small factor."""
from __future__ import annotations

PROCESS = 200e6          # a worker process: Python, numpy, OpenCV, torch imports
ALEXNET_PARAMS = 57e6    # torchvision AlexNet (head 9216 -> 4096 -> 4096 dominates)
ACT_PER_IMAGE_224 = 30e6  # AlexNet training activations + gradients per image at 224 px (fp32)


def classifier_training(c, params: float = ALEXNET_PARAMS, activations_224: float = ACT_PER_IMAGE_224) -> float:
    """The classifier stage: both image sets in memory (uint8, (n, s, s, 3)), the model with its
    gradients and Adam moments (4 x fp32 parameters), one batch's activations. ``params`` and
    ``activations_224``: the network's, as its classifier entry declares them (AlexNet's by default)."""
    t, s = c.training, c.input_size
    images = (t.train_images + t.val_images) * s * s * 3
    return images + 16 * params + t.batch_size * activations_224 * (s / 224) ** 2


def render_worker(c) -> float:
    """One source-domain render worker: its chunk of 250 images and float scratch per image."""
    return PROCESS + 250 * c.input_size ** 2 * 3 * 9


def data_worker(syn) -> float:
    """One data worker: a BigBIRD or AVD view rendered in float64 (~20 full-frame buffers: colour,
    depth, masks, noise) plus its JPEG."""
    px = max(syn.bigbird_width * syn.bigbird_height, syn.avd_width * syn.avd_height)
    return PROCESS + 20 * 8 * px


def simulate_realization(sim, n_classes: int = 3) -> float:
    """One realization in a simulate batch: its draws, and the With Uncertainty fusion's GP
    predictive over its N_x localization samples ((C, F, K, K) covariances, ~3 float64 copies)."""
    K, F = sim.track_steps, 3
    n_x = max(sim.n_loc_samples, 1)
    draws = 8 * K * F * (3 * sim.n_samples + 3) + 8 * n_x * K * 2 * 2
    fusion = 8 * 3 * n_x * n_classes * F * (K * K + K)
    return draws + fusion


def simulate_results(sim, n_methods: int = 6) -> float:
    """simulate's results table, kept until written: one row per (scenario, method, realization,
    step), ~100 float64 in its copies."""
    return 800.0 * sim.realizations * len(sim.scenarios) * n_methods * sim.track_steps


def bootstrap(n_boot: int, groups: int, width: int) -> float:
    """The hierarchical bootstrap (``statistics.resampler.Resampler``): about nine (B, T, width) arrays
    of 8 bytes (uniforms, member indices, counts, gathered values, weights)."""
    return 9 * 8 * float(n_boot) * groups * width


def kept_rows(realizations: float, k: int, n_classes: int, n_methods: int = 6) -> float:
    """Results kept until written: per method the log posteriors (R, K, C) and their result rows
    (~25 columns of 8 bytes per (realization, step))."""
    return realizations * n_methods * k * (8 * n_classes + 25 * 8)


def randomized_cell(ev, k: int, n_classes: int, n_methods: int = 6) -> float:
    """One evaluate cell's kept results (``kept_rows``) over its randomized settings."""
    return kept_rows(ev.randomized.realizations * max(len(ev.randomized.sigmas_m), 1), k, n_classes, n_methods)


def fused_batch(n_x: int, k: int, n_classes: int, n_components: int = 4, chunk: int = 25) -> float:
    """One fused batch of the randomized experiments (``grid.experiments.randomized``): ``chunk``
    realizations' estimates and localization samples (R, N_x, K, 2) and, per call, at least one
    realization's N_x trajectories with their per-step predictive terms (~4 float64 (C, F) arrays)."""
    return 8 * chunk * n_x * k * 2 * 2 + 8 * 4 * max(n_x, 100_000) * k * n_classes * n_components
