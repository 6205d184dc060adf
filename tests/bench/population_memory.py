"""Peak memory and seconds of vf.evaluate_population on a generated population (T targets x K tracks, four
methods, one metric) against its memory estimate (not part of make bench).

    python tests/bench/population_memory.py T K N_BOOT
"""
import sys, resource, time
import numpy as np, pandas as pd
import viewfuse as vf
T, K, nb = int(sys.argv[1]), int(sys.argv[2]), int(float(sys.argv[3]))
rng = np.random.default_rng(0)
rows = []
methods = ["with_uncertainty", "model_based", "simple_bayes", "view_independent"]
for t in range(T):
    for k in range(K):
        for m in methods:
            rows.append({"target": f"t{t}", "track": k, "method": m, "prob_truth_final": rng.uniform()})
df = pd.DataFrame(rows)
from viewfuse import api
cells = df.copy(); cells["setting"] = "default"
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
t0 = time.perf_counter()
out = vf.evaluate_population(df, metrics=["prob_truth_final"], n_boot=nb)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(f"{T} targets x {K} tracks, {nb} draws: estimate {api._population_bytes(cells, nb) / 1e9:.2f} GB, "
      f"peak growth {(peak - base) / 1e9:.2f} GB, {time.perf_counter() - t0:.1f} s")
