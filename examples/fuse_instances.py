"""Class models that know instances differ, on hand-made arrays: three classes of five training
instances each, every instance its class's viewpoint curve plus an offset of its own; then unseen
instances (offsets never seen) fused along 8-view tracks by With Uncertainty on the pooled models
and on the models with the instance term (vf.fit_models(..., instances=...)).
Run: python examples/fuse_instances.py"""
import numpy as np

import viewfuse as vf

rng = np.random.default_rng(0)
CLASSES = ("mug", "bowl", "can")
N_INST, N_VIEWS, OFFSET_SD, NOISE_SD = 5, 16, 0.06, 0.02


def curve(c, th):
    """Class c's mean scores (two components) over the viewing direction."""
    peak = np.cos(th - 2 * np.pi * c / 3)
    return np.stack([0.5 + 0.08 * peak, 0.5 - 0.06 * peak], axis=-1)


angles = np.linspace(0.0, 2 * np.pi, N_VIEWS, endpoint=False)
samples, instances = {}, {}
for c, name in enumerate(CLASSES):
    offsets = rng.normal(0, OFFSET_SD, (N_INST, 2))            # one deviation per instance, every view
    scores = [curve(c, angles) + offsets[i] + rng.normal(0, NOISE_SD, (N_VIEWS, 2)) for i in range(N_INST)]
    samples[name] = (np.tile(angles, N_INST), np.concatenate(scores))
    instances[name] = np.repeat([f"{name}{i}" for i in range(N_INST)], N_VIEWS)
pooled = vf.fit_models(samples, restarts=0)
hier = vf.fit_models(samples, restarts=0, instances=instances)
for d in hier.diagnostics:
    print(f"{d['class']:5s} component {d['component']}: instance amplitude {d['instance_amplitude']:.4f} "
          f"(95 % CI {d['instance_amplitude_ci'][0]:.4f} to {d['instance_amplitude_ci'][1]:.4f}), length scale "
          f"{d['instance_length_scale']:.2f}, ratio to the class amplitude {d['instance_ratio']:.2f}; pooled noise "
          f"{d['pooled']['noise']:.4f} -> {d['noise']:.4f}")

# Unseen instances: a new offset each, K = 8 views along an arc, MC-dropout samples around the score.
K, n_tracks, final = 8, 60, {"with_uncertainty": [], "with_uncertainty_instance": []}
for r in range(n_tracks):
    truth = r % 3
    bearing = rng.uniform(0, 2 * np.pi) + np.linspace(0, 1.2, K)
    cameras = 2.0 * np.stack([np.cos(bearing), np.sin(bearing)], axis=1)
    s = curve(truth, bearing) + rng.normal(0, OFFSET_SD, 2) + rng.normal(0, NOISE_SD, (K, 2))
    dropout = s[:, None, :] + rng.normal(0, 0.01, (K, 8, 2))
    final["with_uncertainty"].append(vf.fuse("with_uncertainty", pooled, cameras=cameras, dropout=dropout,
                                             sigma=0.05, n_x=10, seed=r)[-1, truth])
    final["with_uncertainty_instance"].append(vf.fuse("with_uncertainty_instance", hier, cameras=cameras,
                                                      dropout=dropout, sigma=0.05, n_x=10, seed=r)[-1, truth])


def mean_ci(v, n_boot=2000):
    """Mean and its 95 % bootstrap interval over the unseen instances."""
    v = np.asarray(v)
    boots = rng.choice(v, (n_boot, len(v))).mean(axis=1)
    return v.mean(), *np.percentile(boots, [2.5, 97.5])


for key, v in final.items():
    p = np.exp(v)
    m, lo, hi = mean_ci(p)
    print(f"{key:26s} P(final) of the truth {m:.3f} (95 % CI {lo:.3f} to {hi:.3f}); confidently wrong "
          f"(P(truth) < 0.01) {np.mean(p < 0.01):.3f}, over {n_tracks} unseen instances")
m, lo, hi = mean_ci(np.exp(final["with_uncertainty_instance"]) - np.exp(final["with_uncertainty"]))
print(f"paired difference, instance term minus pooled: {m:+.3f} (95 % CI {lo:+.3f} to {hi:+.3f})")
