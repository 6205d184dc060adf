"""The fusion on hand-made arrays: three classes whose two scores vary with the viewing direction,
GP class models fitted from (angle, score vector) samples, and one five-view track fused with every
registered method that applies. Run: python examples/fuse_arrays.py"""
import numpy as np

import viewfuse as vf

rng = np.random.default_rng(0)
CLASSES = ("mug", "bowl", "can")

# Training views: 36 directions per class; class c looks most like itself from direction 2πc/3.
angles = np.linspace(0.0, 2 * np.pi, 36, endpoint=False)
samples = {}
for c, name in enumerate(CLASSES):
    peak = np.cos(angles - 2 * np.pi * c / 3)
    scores = np.stack([0.5 + 0.3 * peak, 0.5 - 0.2 * peak], axis=1) + rng.normal(0, 0.02, (36, 2))
    samples[name] = (angles, scores)
models = vf.fit_models(samples, restarts=0)

# A track: five camera positions on a 2 m arc around the object at the origin, the object seen by
# a "bowl" classifier with MC dropout (N_s = 8 samples per view), pose estimates 0.2 m off.
K, truth = 5, CLASSES.index("bowl")
bearing = np.linspace(1.6, 2.6, K)
cameras = 2.0 * np.stack([np.cos(bearing), np.sin(bearing)], axis=1)
mean, _ = models.marginal(np.stack([np.cos(bearing), np.sin(bearing)], axis=1))   # (K, C, F)
dropout = mean[:, truth, None, :] + rng.normal(0, 0.03, (K, 8, 2))
own = rng.dirichlet([2.0, 6.0, 2.0], size=(K, 8))          # each candidate's own score (Simple Bayes)
estimates = cameras + rng.normal(0, 0.2, cameras.shape)

for key in vf.methods():
    try:
        log_post = vf.fuse(key, models, cameras=estimates, dropout=dropout, own=own, sigma=0.2, n_x=50, seed=1)
    except ValueError as e:               # e.g. the Dirichlet method needs Dirichlet models
        print(f"{key:18s} skipped: {e}")
        continue
    p = np.exp(log_post[-1])
    print(f"{key:18s} P(final) = " + ", ".join(f"{n} {v:.3f}" for n, v in zip(CLASSES, p)))
