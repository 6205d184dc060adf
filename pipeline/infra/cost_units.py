"""The cost model's measured constants (pipeline/infra/cost.py): seconds of one unit of work on
the development machine (2 cores, AMD EPYC; Xeon where said), each with where it was measured, the
stages' processes' resident bytes before their work and their fixed seconds. Kept apart from the
formulas so a re-measurement (tests/bench/bench_cost.py) changes one file.
"""
from __future__ import annotations

from pipeline.infra.budget import GIB

# --- per-unit seconds ---------------------------------------------------------------------------
# One With Uncertainty trajectory of K = 9 steps over C = 4 candidates: 32,000 trajectories/s in the
# paper-grade evaluate run (docs/benchmarks.md, "the paper-grade preset"). Cost grows as K^1.5 and
# linearly in C: bench_cost.py measured 2.8 and 3.2 times the (9, 4) cost at K = 18, and 1.7 and 3.2
# times at C = 8, in two runs under loads of 9 and 6 on the 2 cores (the ratios, not the level,
# set the scaling; the level there was 2-3x slower than this constant).
WU_TRAJECTORY_S = 1 / 32_000
# Everything else per (cell, realization, step): Model Based and the other methods, metrics, rows,
# writing: 28 s over 83 tracks x 2001 realizations x 9 steps in the same run.
ROW_S = 28 / (83 * 2001 * 9)
# Model Based on one one-step track (the bias maps: steps^2 per view): 15 s over the same run's
# 83 x 2001 x 9 trajectory-steps.
MB_STEP_S = 15 / (83 * 2001 * 9)
# Real data's evaluate (the likelihood branch's real_category run, ETH-80, 72 targets x 2 tracks,
# 139 cells, 128 views a class, 3801 AVD crops x 13 components, bootstrap 2000, likelihood_tail =
# student_t): 620 s under load (159 CPU s; about 160 s idle), split by its manifest's timings into
# population 44 %, domain fit 27 %, statistics 22 %. Parts the grid's trajectories leave out, each
# set to its share of the 160 s:
# - each cell's own work whatever its realizations (its candidates' GP predictions along the track,
#   its methods' set-up and guarded calls, its reduction): 0.45 s a cell, about the population's
#   0.36 s a cell there and half the smoke run's 0.93 s a cell at load 5.7 (its trajectories are
#   few: the whole population is this);
CELL_S = 0.45
# - the test-domain fit before the grid (each labelled AVD crop's residual per component against its
#   class's GP on that class's views, the cross-fits, the Student-t tails): 43 s over 3801 x 13 x 128;
DOMAIN_UNIT_S = 43 / (3801 * 13 * 128)
# - the population statistics after it (the bootstrap of every metric over the resampled units):
#   35 s for its 72 x 2 (target, track) units at 2000 resamples, clustered by category (a level
#   above the targets: twice the work of target-level clustering), linear in units and resamples.
#   (Row-linear it would give the idle synthetic evaluate 71 s of statistics: its whole stage is 49.)
STAT_UNIT_S = 35 / (72 * 2 * 2000 * 2)
# - likelihood_tail = student_t runs With Uncertainty and Model Based again with a Student-t
#   likelihood: 92 s beside With Uncertainty's 138 s in the same run (0.66 of it).
STUDENT_T_SHARE = 0.66
# View planning, per episode step (the belief update on the history) at N_x ~ 37 and C = 4: 20.6 s
# over 540 episodes of at most 10 steps on the default run; one information-gain decision at 64
# draws per class, horizon 1: 2.8 ms median (docs/benchmarks.md, "View planning"). A step grows with
# the history as K^1.5 (the budget, calibrated at 10), with N_x and with C; a decision with the draws,
# C and the nodes within the horizon.
PLAN_STEP_S = 20.6 / (540 * 10)
PLAN_DECISION_S = 2.8e-3
PLAN_MOVES = 6  # moves from an AVD node (forward, backward, left, right, rotate cw, ccw): the horizon's branching
# simulate (bench_cost.py, load 6 on 2 cores): a model_uncertainty realization of K = 21 steps
# 1.44 ms at 20 measurement samples (split 1.2 ms + 0.012 ms a sample from 80 samples' 3.9 ms at
# load 9); a localization_bias realization 34 ms at 100 localization samples (65 and 142 ms at 100
# and 200 under load 9: linear in them); the GP fits 4.0 s per (restarts + 1); a sweep point 0.5 s
# on top of its realizations (the small sweep's 20 s, docs/benchmarks.md).
SIM_MU_S, SIM_MU_SAMPLE_S, SIM_LB_SAMPLE_S, SIM_FIT_S, SIM_SWEEP_POINT_S = 1.2e-3, 1.2e-5, 3.4e-4, 4.0, 0.5
# The classifier (AlexNet, `viewfuse classifier`, idle Xeon 2.8 GHz, 2 cores, docs/benchmarks.md):
# 19 s to render 7600 source images; an epoch of 6400 images at 112 px and batch 64, 44 s; an early
# epoch (80 px crops, the compact head) 26 s, scaled by the area of their sides.
CLASSIFIER_RENDER_IMAGE_S = 19 / 7600
CLASSIFIER_IMAGE_EPOCH_S = 44 / 6400
CLASSIFIER_EARLY_EPOCH_SHARE = 26 / 44
# The features stage's MC-dropout head: 1.5 ms a (crop, sample) row, and the backbone 9.4 ms a
# 112 px crop (bench_cost.py: AlexNet, load 6 on 2 cores; 4.3 and 34 ms under load 9).
HEAD_ROW_S, BACKBONE_CROP_S = 1.5e-3, 9.4e-3
# Other networks, as a share of AlexNet's cost a crop at the same size and samples: EfficientNet-Lite0's
# head is one 1280-wide layer, not AlexNet's two 4096-wide ones (real_full idle: 213 s for 16,374
# crops at 160 px, 1 + 10 passes, with the stage's fixed work: 12 ms a crop against AlexNet's 36).
ARCH_CROP_SHARE = {"alexnet": 1.0, "efficientnet_lite0": 0.35}
# The data stage: 54 CPU s for the default synthetic world (the main job's row in docs/benchmarks.md,
# Xeon idle, 28 s wall), counted against its 1887 BigBIRD megapixels (AVD frames included).
RENDER_MP_S = 54 / (12 * 120 * 1280 * 1024 / 1e6)
# The data stage of photographs on real AVD geometry (real_imagery, turntable sources): real_full
# idle 69 s for 16,374 training views and frames read, pasted, degraded and encoded, less the
# stage's fixed work (docs/benchmarks.md, "Current figures"; 4.3 min before the writers were batched).
WRITE_IMAGE_S = 59 / 16_374
# The models stage: 8-10 s a seed for 12 classes x 12 components (the union of the 12 candidate
# sets' top 4: every output of the synthetic classifier) x 120 views x (5 restarts + 1) (make study;
# 10 s wall idle for the whole synthetic stage, docs/benchmarks.md): one GP fit a (class, component,
# start). A fit's cost grows as its views^1.6 over 36-128 views (fit_class_models timed on the 2-core
# AMD EPYC at load 4.6, 12 classes x 12 components, one start: 0.9 s at 36 views, 6.3 s at 120;
# 24 classes at 128 views 15 s), not as their cube.
MODEL_FIT_S = 9 / (12 * 12 * 6)
MODEL_FIT_VIEWS_POWER = 1.6
# The components fitted are the union of each candidate set's top models.n_components: 11-14 with
# n_components = 4 over 12 and over 72 candidate sets (the crops and likelihood branches' real runs:
# the sets' top scores overlap), 5 over the smoke run's 5 sets (every class), 12 in the synthetic run.
UNION_COMPONENTS_SHARE = 3

# --- the stages' processes, before their work ----------------------------------------------------
# Resident bytes after importing every project module a stage reaches (its code version's module
# list) with their libraries: python -c "import ...; psutil rss" here. The torch stages map about
# 3.5 GiB of address space for that (what an RLIMIT_AS must leave room for); the others 0.7 GiB.
BASE = {"data": 0.14 * GIB, "classifier": 0.58 * GIB, "features": 0.60 * GIB, "models": 0.67 * GIB,
        "evaluate": 0.74 * GIB, "report": 0.72 * GIB, "simulate": 0.24 * GIB}
BASE_MAPPED = {"data": 0.7 * GIB, "simulate": 0.75 * GIB}
TORCH_MAPPED = 3.5 * GIB

# --- the stages' fixed work: seconds whatever the settings ---------------------------------------
# Process start and imports, pools started, models loaded, the outputs written, and per stage what
# no key multiplies: the smallest chain (configs/smoke.toml), idle, is almost nothing but this
# (docs/benchmarks.md: data 16 s, classifier 33 s, features 26 s, models 7 s, report 29 s on the
# Xeon), and the real chains' stages with little work (real: classifier 3 s with ImageNet weights,
# models 6 s, report 10 s) bound it from below. The smoke evaluate is now mostly its cells'
# own work (CELL_S): 29.4 s wall, 25.9 CPU s for 20 cells at 4 steps (32.7 s, 27.1 CPU s at 40 steps)
# on the 2-core AMD EPYC at load 5.7 (`viewfuse evaluate --config configs/smoke.toml --set
# evaluate.track_length=40`, December 7), of which the population 18.7 s and the statistics 6.9 s.
# Each is set so both sides lie within a factor of two (tests/stages/test_smoke_run.py checks the
# smoke chain's manifests against the estimates, tests/pipeline/infra/test_cost_recorded.py the
# recorded real runs').
# models: 3.5 s sits between the smoke chain's models stage run in its own process (7 s idle, Xeon)
# and run after the earlier stages in one process (1.9 s, their imports already paid).
# classifier: 12 s, between the smoke chain's classifier idle on the AMD EPYC (9.6 s wall, fresh-clone
# test run, December 7) and on the Xeon (33 s, an earlier code's start-up), so 2 x wall holds on both.
FIXED_S = {"data": 10.0, "classifier": 12.0, "features": 15.0, "models": 3.5, "evaluate": 12.0,
           "report": 16.0, "simulate": 5.0}
FIXED_LOADED_WEIGHTS_S = 3.0   # the classifier stage with weights it only loads (imagenet, path)
