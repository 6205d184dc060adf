"""Every figure function of reports/ renders without text overlap or clipping (the report's own
checker, ``figure_text_problems``) once finished (``finish_figure``, what every save runs), for
generated data: values from ±1e-300 to ±1e300, all equal, ties at 0, one target, one track,
single-track targets without a CI, unbounded CI ends, missing optional blocks, long names.

Cases hypothesis found failing are kept as explicit ``@example``s. The run is derandomized (the
same cases on every machine) and prints how many generated cases it ran."""
from __future__ import annotations

import os

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from pipeline.evaluation.metrics.labels import comparison_key, comparisons
from pipeline.method.methods.dirichlet import DIRICHLET
from pipeline.method.names import MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY
from reports.shared.checks import figure_text_problems
from reports.shared.layout import finish_figure
from reports.shared.numbers import Estimate

# each case lays a figure out two or three times (one to several seconds of CPU): make test runs a
# few generated cases per figure besides the explicit examples; VIEWFUSE_FIGURE_EXAMPLES=25 (or
# more) runs the thorough sweep. make test-fast skips the file.
pytestmark = pytest.mark.slow

CASES = {"n": 0}
N_EXAMPLES = int(os.environ.get("VIEWFUSE_FIGURE_EXAMPLES", "3"))
SETTINGS = settings(max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])
METHODS = (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES, DIRICHLET)

SPECIAL = (0.0, 1e-300, -1e-300, 1e300, -1e300, 1.0, -1.0, 1e4, -1e4, 0.5, 1e-5)
wide = st.one_of(st.sampled_from(SPECIAL), st.floats(-1e300, 1e300, allow_nan=False, allow_infinity=False),
                 st.floats(-1e5, 1e5, allow_nan=False))
names = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,70}( [a-z]{1,15}){0,3}", fullmatch=True)
unit = st.floats(0.0, 1.0, allow_nan=False)


@pytest.fixture(scope="module", autouse=True)
def _count(request):
    yield
    tr = request.config.pluginmanager.get_plugin("terminalreporter")
    line = f"figure properties: {CASES['n']} generated cases rendered clean"
    if tr is not None:
        tr.write_line(line)
    else:
        print(line)


def _clean(fig, name: str) -> None:
    CASES["n"] += 1
    finish_figure(fig)
    assert figure_text_problems(fig, name) == []


@st.composite
def estimates(draw, bounded: bool = False):
    """A contract entry {value, ci_low, ci_high}: ends may be missing (None) or infinite."""
    a, b, c = sorted(draw(st.lists(wide, min_size=3, max_size=3)))
    if draw(st.booleans()):
        a = b = c = draw(wide)                                     # all equal
    lo = draw(st.sampled_from(["keep", "none", "inf"])) if not bounded else "keep"
    hi = draw(st.sampled_from(["keep", "none", "inf"])) if not bounded else "keep"
    return {"value": b, "ci_low": None if lo == "none" else -math.inf if lo == "inf" else a,
            "ci_high": None if hi == "none" else math.inf if hi == "inf" else c}


@st.composite
def populations(draw):
    targets = draw(st.lists(names, min_size=1, max_size=4, unique=True))
    keys = [comparison_key(*c) for c in draw(st.lists(st.sampled_from(comparisons()), min_size=1, max_size=3,
                                                         unique=True))]
    methods = draw(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True))
    metrics = ("correct_final", "prob_truth_final", "log10_mgr95_final")
    tracks = {t: draw(st.integers(1, 3)) for t in targets}

    def est(single: bool):
        e = draw(estimates())
        return {**e, "ci_low": None, "ci_high": None} if single else e
    return {
        "targets": targets, "methods": methods,
        "tracks": [{"target": t, "scan": "s"} for t in targets for _ in range(tracks[t])],
        "paired_per_target": {k: {t: {m: est(tracks[t] == 1) for m in metrics} for t in targets} for k in keys},
        "paired": {k: {m: est(False) for m in metrics} for k in keys},
        "per_target": {t: {m: {x: est(tracks[t] == 1) for x in metrics} for m in methods} for t in targets},
        "pooled": {m: {x: est(False) for x in metrics} for m in methods},
    }


def _rows(methods, steps, R, values):
    return pd.DataFrame([{"method": m, "realization": r, "step": k, "p_truth": values[i % len(values)],
                          "log10_mgr": values[(i * 7 + 3) % len(values)]}
                         for i, (m, r, k) in enumerate((m, r, k) for m in methods for r in range(R) for k in steps)])


# ----------------------------------------------------------------- population figures

@SETTINGS
@given(populations(), st.sampled_from([None, "target", "scan", "category", "crossed"]))
def test_forest(pop, cluster):
    from reports.main.figures_results import fig_forest
    fig = fig_forest({**pop, "cluster": cluster})
    _clean(fig, "forest.png")
    if cluster in ("category", "crossed"):   # the pooled rows say over what they vary
        assert ("categories" if cluster == "category" else "crossed") in fig._suptitle.get_text()


@SETTINGS
@given(populations())
def test_per_target(pop):
    from reports.main.figures_results import fig_per_target
    _clean(fig_per_target(pop), "per_target.png")


@st.composite
def reliability_blocks(draw):
    methods = draw(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True))
    n = draw(st.integers(1, 6))
    rel, pooled, counts = {}, {}, {}
    for m in methods:
        conf = draw(st.lists(st.one_of(st.none(), unit), min_size=n, max_size=n))
        rel[m] = {"final": {"confidence": conf, "accuracy": draw(st.lists(st.one_of(st.none(), unit), min_size=n,
                                                                          max_size=n)),
                            "share": draw(st.lists(unit, min_size=n, max_size=n)),
                            "lower": list(np.linspace(0, 1, n + 1)[:-1]), "upper": list(np.linspace(0, 1, n + 1)[1:])}}
        pooled[m] = {"ece_final": {"value": draw(unit)}}
        counts[m] = np.asarray(draw(st.lists(st.integers(0, 10 ** 9), min_size=n, max_size=n)))
    return {"reliability": rel, "pooled": pooled}, (counts if draw(st.booleans()) else None)


@SETTINGS
@given(reliability_blocks())
def test_reliability(block):
    from reports.main.figures_calibration import fig_reliability
    pop, counts = block
    _clean(fig_reliability(pop, counts=counts), "reliability.png")


@SETTINGS
@given(st.lists(st.sampled_from(("gp", "gp_plus_dropout", "gp_calibrated", "extra")), max_size=3, unique=True),
       st.lists(unit, min_size=0, max_size=20), unit, unit)
def test_pit(kinds, pit, share, cover):
    from reports.main.figures_calibration import fig_pit
    domain = {k: {"overall": {"pit": pit or [1.0], "share_gt3": share, "coverage95": cover}} for k in kinds}
    _clean(fig_pit(domain), "pit.png")


# ----------------------------------------------------------------- the detailed track

@SETTINGS
@given(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True), st.integers(1, 14),
       st.integers(1, 3), st.lists(unit, min_size=1, max_size=8), st.integers(0, 30),
       st.lists(names, max_size=14))
def test_biased(methods, K, R, values, n_classes, images):
    from reports.main.figures_results import fig_biased
    _clean(fig_biased(_rows(methods, range(K), R, values), n_classes, images), "biased_ptruth.png")


@SETTINGS
@given(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True), st.integers(1, 14),
       st.integers(1, 4), st.lists(st.one_of(wide, st.just(math.inf)), min_size=1, max_size=8),
       st.sampled_from(("p_truth", "log10_mgr")))
def test_bands(methods, K, R, values, column):
    from reports.main.figures_results import fig_bands
    df = _rows(methods, range(K), R, values)
    if column == "p_truth":
        df["p_truth"] = np.clip(np.nan_to_num(df["p_truth"], posinf=1.0), 0, 1)
    fig, _ = fig_bands(df, column, "P(ground-truth class)" if column == "p_truth" else "log10 MGR", "a title")
    _clean(fig, f"randomized_{column}.png")


@st.composite
def sensitivity_summaries(draw):
    methods = draw(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True))
    sigmas = draw(st.lists(st.floats(0.0, 10.0), min_size=1, max_size=5, unique=True))

    def e(bounded_unit: bool):
        d = draw(estimates())
        if bounded_unit:
            d = {k: (None if v is None else min(max(v, 0.0), 1.0)) for k, v in d.items()}
        return Estimate(d["value"], d["ci_low"], d["ci_high"])
    return {f"sigma={s:g}": {"sigma_m": s, "n_realizations": draw(st.integers(1, 100)),
                             "methods": {m: {"correct_final": e(True), "log10_mgr95_final": e(False)}
                                         for m in methods}} for s in sigmas}


# found: a method present in one setting only crashed the figure (no estimate to draw there)
SENSITIVITY_GAP = {
    "a": {"sigma_m": 0.1, "n_realizations": 3,
          "methods": {WITH_UNCERTAINTY: {"correct_final": Estimate(0.5, 0.0, 1.0),
                                         "log10_mgr95_final": Estimate(1e300, -1e300, math.inf)}}},
    "b": {"sigma_m": 0.3, "n_realizations": 3,
          "methods": {MODEL_BASED: {"correct_final": Estimate(0.5, None, None),
                                    "log10_mgr95_final": Estimate(-1e-300, None, 1e4)}}}}


@SETTINGS
@given(sensitivity_summaries())
@example(SENSITIVITY_GAP)
def test_sensitivity(summ):
    from reports.main.figures_results import fig_sensitivity
    _clean(fig_sensitivity(summ), "sensitivity.png")


coords = st.floats(-1e4, 1e4, allow_nan=False)


@SETTINGS
@given(st.lists(st.tuples(coords, coords), min_size=1, max_size=12), st.booleans(),
       st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), max_size=4), st.booleans())
@example([(0.0, 0.015625)], False, [], False)   # found: one camera, an equal-aspect axis squeezed to two touching labels
@example([(-1.7598514790610627e-158, -1.1), (-1.628421834887212e-170, -1644.9096431742764),
          (-8092.023694382088, 3038.5257396874113), (2428.7501124364735, -2.220446049250313e-16),
          (5824.8683094758835, 3.6), (1.5, 6641.801986296723), (2.821213028641448e-221, 0.99999), (0.0, 0.0)],
         False, [], False)   # found: cameras metres apart on a kilometre axis, their number labels touching
def test_track(cams, headings, biases, objects):
    from reports.main.figures_results import fig_track
    track = {"camera_xy": [list(c) for c in cams]}
    if headings:
        track["heading_rad"] = list(np.linspace(0, 6, len(cams)))
    if objects:
        track["object_xy_est"], track["object_xy_truth"] = list(cams[0]), list(cams[-1])
    _clean(fig_track(track, biases), "track.png")


# ----------------------------------------------------------------- the class models

@st.composite
def gp_blocks(draw):
    C, F = draw(st.integers(1, 5)), draw(st.integers(1, 5))   # 12 × 12: test_figure_layout (one case)
    G, N, T = 4, 6, 12
    scale = draw(st.sampled_from((1e-300, 1e-5, 1.0, 1e5, 1e300)))
    base = draw(st.floats(-1.0, 1.0))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 16)))
    flat = draw(st.booleans())
    noise = (lambda *shape: np.zeros(shape)) if flat else (lambda *shape: rng.normal(0, 1, shape))
    gp = {"grid": np.linspace(-1.5, 1.5, G), "raster_mean": scale * (base + noise(C, F, G, G)),
          "ring_theta": np.linspace(0, 2 * np.pi, T, endpoint=False), "ring_mean": scale * (base + noise(C, F, T)),
          "ring_std": np.abs(scale * noise(C, F, T)) * 0.1, "train_theta": np.tile(np.linspace(0, 6, N), (C, 1)),
          "train_y": scale * (base + noise(C, F, N))}
    classes = draw(st.lists(names, min_size=C, max_size=C))
    comps = draw(st.lists(names, min_size=F, max_size=F))
    inputs = None if draw(st.booleans()) else [[0.5, 0.5], [-0.3, 0.9]]
    return gp, classes, comps, inputs


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(gp_blocks())
def test_gp_rasters(block):
    from reports.main.figures_models import fig_gp_rasters
    _clean(fig_gp_rasters(*block), "gp_rasters.png")


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(gp_blocks())
def test_gp_ring(block):
    from reports.main.figures_models import fig_gp_ring
    _clean(fig_gp_ring(*block), "gp_ring.png")


@st.composite
def bias_map_blocks(draw):
    K, C, B = draw(st.integers(1, 6)), draw(st.integers(2, 8)), 5   # a posterior over 2+ candidates
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 16)))
    post = rng.dirichlet(np.ones(C), (K, B, B)).transpose(0, 3, 1, 2) if not draw(st.booleans()) \
        else np.full((K, C, B, B), 1.0 / C)
    ext = draw(st.floats(0.01, 10.0))
    classes = draw(st.lists(names, min_size=C, max_size=C))
    target = classes[0] if draw(st.booleans()) else "not a candidate"
    images = draw(st.lists(names, max_size=K))
    return {"posterior": post, "bias_x": np.linspace(-ext, ext, B), "bias_y": np.linspace(-ext, ext, B)}, \
        classes, target, images


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(bias_map_blocks())
def test_bias_maps(block):
    from reports.main.figures_models import fig_bias_maps
    _clean(fig_bias_maps(*block), "bias_maps.png")


# ----------------------------------------------------------------- planning

PLANNERS = ("info_gain", "known_pose", "random", "fixed", "orbit", "hindsight")


@st.composite
def planning_blocks(draw):
    planners = draw(st.lists(st.sampled_from(PLANNERS + ("a_new_planner_with_a_long_name",)), min_size=1,
                             max_size=7, unique=True))
    budget = draw(st.integers(1, 15))

    def curve():
        return [draw(estimates(bounded=True)) for _ in range(budget)]
    return {"budget": budget, "planners": planners,
            "curves": {p: {k: curve() for k in ("correct", "confident_error", "nll")} for p in planners}}


@SETTINGS
@given(planning_blocks())
def test_planning_curves(block):
    from reports.main.planning import fig_curves
    _clean(fig_curves(block), "planning_curves.png")


@SETTINGS
@given(st.lists(st.tuples(coords, coords), min_size=1, max_size=30), st.integers(1, 8), st.booleans())
def test_planning_map(views, n, fixed):
    from reports.main.planning import fig_map
    xy = [list(v) for v in views[:n]]
    paths = {"info_gain": {"xy": xy, "nodes": list(range(len(xy)))}}
    if fixed:
        paths["fixed"] = {"xy": xy[::-1], "nodes": list(range(len(xy)))}
    _clean(fig_map({"views_xy": [list(v) for v in views], "paths": paths, "object_xy": list(views[0])}),
           "planning_map.png")


# ----------------------------------------------------------------- the simulation report

@SETTINGS
@given(st.integers(1, 14), st.integers(1, 4), st.lists(st.one_of(wide, st.just(math.inf)), min_size=1, max_size=8),
       st.sampled_from(("p_truth", "log10_mgr")))
def test_simulate_bands(K, R, values, column):
    from reports.simulate.page import fig_bands_vs
    df = _rows((WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES), range(K), R, values)
    if column == "p_truth":
        df["p_truth"] = np.clip(np.nan_to_num(df["p_truth"], posinf=1.0), 0, 1)
    _clean(fig_bands_vs(df, column, "y", "a title — model uncertainty"), f"sim_{column}.png")


@SETTINGS
@given(st.lists(st.sampled_from(METHODS), min_size=1, max_size=4, unique=True), st.integers(1, 30),
       st.floats(0.5, 1.0), unit)
def test_confident_errors(methods, K, threshold, rate):
    from reports.simulate.claims import fig_confident_errors
    conf = {m: {"rate": [rate] * K, "ci_low": [rate / 2] * K, "ci_high": [min(1.0, rate * 2)] * K} for m in methods}
    _clean(fig_confident_errors(conf, threshold, "Confident errors per step — a long scenario title"),
           "confident_errors.png")


@st.composite
def measurement_rows(draw):
    C = draw(st.integers(2, 6))
    K = draw(st.integers(1, 10))
    classes = draw(st.lists(names, min_size=C, max_size=C))
    scale = draw(st.sampled_from((1e-300, 1.0, 1e5, 1e300)))
    biased = draw(st.booleans())
    rows = []
    for f in range(C):
        for k in range(K):
            rows.append({"scenario": "s", "component": f, "step": k, "true_x": float(k), "true_y": 0.0,
                         "est_x": float(k) + (0.3 if biased else 0.0), "est_y": 0.0,
                         "class_mean": scale * np.linspace(0, 1, C), "class_std": scale * 0.1 * np.ones(C),
                         "class_mean_est": scale * np.linspace(1, 0, C), "samples": [scale * 0.5] * (k % 3 + 1),
                         "nominal": scale * 0.5, "noised": scale * (0.5 + 0.1 * biased)})
    return pd.DataFrame(rows), classes


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(measurement_rows())
def test_simulate_measurements(block):
    from reports.simulate.page import fig_measurements
    ex, classes = block
    _clean(fig_measurements(ex, "s", classes, 0), "measurements.png")


@st.composite
def sweeps(draw):
    from reports.simulate.claims import SHORT
    keys = draw(st.lists(st.sampled_from(sorted(SHORT) + ["a_claim_the_page_has_no_short_name_for"]), min_size=1,
                         max_size=6, unique=True))
    noise = draw(st.lists(st.sampled_from((1e-6, 1e-4, 1e-3, 1e-2, 0.1, 1.0)), min_size=1, max_size=6, unique=True))
    sig = draw(st.lists(st.sampled_from((0.0, 0.1, 0.3, 0.5, 1.0, 2.0)), min_size=1, max_size=6, unique=True))
    recs = [{"key": k, "noise": v, "sigma_max": s, "predictive_std": math.sqrt(v), "holds": draw(st.booleans()),
             "ci_side": draw(st.sampled_from(("holds", "fails", "spans"))), "value": draw(wide)}
            for k in keys for v in noise for s in sig]
    best = {"noise": noise[0], "sigma_max": sig[-1]} if draw(st.booleans()) else {}
    return {"grid": {"noise": noise, "sigma_max": sig, "name": "a", "realizations": 30}, "records": recs,
            "default": {"noise": noise[-1], "sigma_max": sig[0]}, "summary": {"best": best}}


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(sweeps(), st.integers(1, 50))
def test_simulate_sweep(sweep, step):
    from reports.simulate.claims import fig_sweep
    _clean(fig_sweep(sweep, step), "claims_sweep.png")


class _Bank:
    """A stand-in for the simulation's GP bank: model points per class and a smooth mean."""

    def __init__(self, C: int, scale: float, seed: int):
        rng = np.random.default_rng(seed)
        self.X = [rng.uniform(-2, 2, (5, 2)) for _ in range(C)]
        self.Y = [rng.uniform(0, 1, (C, 5)) for _ in range(C)]
        self.C, self.scale = C, scale

    def marginal(self, pts):
        ang = np.arctan2(pts[:, 1], pts[:, 0])
        mean = self.scale * np.cos(ang[:, None, None] + np.arange(self.C)[None, :, None]
                                   + np.arange(self.C)[None, None, :])
        return mean, np.ones_like(mean)


@settings(SETTINGS, max_examples=N_EXAMPLES)
@given(st.integers(2, 6), st.sampled_from((1e-300, 1.0, 1e300)), st.integers(0, 99), st.booleans(),
       st.lists(names, min_size=6, max_size=6))
# found failing: long names in the panel titles squeezed the maps until the legend covered the ticks
@example(6, 1e-300, 0, False, ['rdZ yaoejkpkgqtijfl gnxupt za', 'EQmzECz4yufEWk dmr qzakto tjuvpxxaayrljsj',
                               'a1nZvIr9gTt5YzD3zUAkjty qia zw u', 'C gzcokq ulkjfmxgegzjco kwqytv',
                               'U cdvde rrxdmrh u', 'E'])
@example(6, 1.0, 0, True, ["A" * 70 + " abcdefghijklmno" * 3] * 6)
def test_simulate_class_maps(C, scale, seed, biased, classes):
    from reports.simulate.page import fig_class_maps
    true_xy = np.c_[np.linspace(-1.5, 1.5, 5), np.ones(5)]
    est = true_xy + 0.2 if biased else None
    _clean(fig_class_maps(_Bank(C, scale, seed), true_xy, est, classes[:C], 0), "class_maps.png")
