"""The score space (``models.score_space``): the transform itself, the models stage's targets in it,
and every GP method equal to its literal oracle on the mapped scores in every space (1e-9)."""
import math

import numpy as np
import pytest

from pipeline.banks.model_bank import fit_from_features, read_training_views
from pipeline.method import score_space as SS
from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty
from pipeline.method.gp import GPClassModels
from pipeline.method.gp_fit import fit_class_models
from pipeline.method.methods.view_independent import ViewIndependent
from pipeline.method.method_base import TrackInput
from tests.stages.test_models_stage import mcfg, write_features
from tests.support.literal_paper import literal_model_based, literal_uncertainty, literal_view_independent

TOL = 1e-9


def test_transforms_by_definition():
    p = np.array([[0.0, 1e-9, 0.3, 0.7 - 1e-9, 1.0]])
    assert SS.to_space(p, "probability") is not None and np.array_equal(SS.to_space(p, "probability"), p)
    lg = SS.to_space(p, "log", 1e-6)
    assert lg[0, 0] == lg[0, 1] == math.log(1e-6) and lg[0, 2] == math.log(0.3) and lg[0, 4] == 0.0
    lo = SS.to_space(p, "logit", 1e-6)
    # 1 - 1e-6 rounds by ~1e-16, which the log-odds' slope 1 / (p (1 - p)) ~ 1e6 turns into ~1e-10
    assert lo[0, 0] == pytest.approx(-lo[0, 4], abs=1e-9) and lo[0, 2] == pytest.approx(math.log(0.3 / 0.7))
    cl = SS.to_space(p, "clr", 1e-6)
    assert np.allclose(cl.sum(axis=-1), 0.0, atol=1e-12)
    assert cl[0, 2] - cl[0, 4] == pytest.approx(math.log(0.3))   # ratios kept, the level removed


@pytest.mark.parametrize("bad", [np.array([0.2, 1.5]), np.array([-0.1, 0.5]), np.array([np.nan, 0.5])])
def test_not_probabilities_are_refused_outside_the_identity(bad):
    with pytest.raises(ValueError, match="probabilities"):
        SS.to_space(bad, "log")
    SS.to_space(np.nan_to_num(bad), "probability")   # the paper's space takes any score


def test_unknown_space_and_floor():
    with pytest.raises(ValueError, match="score space"):
        SS.to_space([0.5], "sqrt")
    with pytest.raises(ValueError, match="floor"):
        SS.to_space([0.5], "log", 0.0)
    assert SS.of_meta({}) == ("probability", SS.DEFAULT_FLOOR)   # a bank from before the key


@pytest.mark.parametrize("space", ["log", "logit", "clr"])
def test_models_stage_fits_on_the_mapped_passes(tmp_path, space):
    """Targets = the mean over dropout passes of the mapped passes (as a step's mean at fusion);
    the bank records its space; the component plan is the probability space's."""
    path = tmp_path / "bigbird.parquet"
    write_features(path)
    prob, _ = fit_from_features(path, mcfg(), progress=False)
    models, extra = fit_from_features(path, mcfg(score_space=space, score_floor=1e-5), progress=False)
    assert models.meta["score_space"] == {"space": space, "floor": 1e-5}
    assert SS.of_models(models) == (space, 1e-5) and extra["fit"]["score_space"] == space
    assert models.components == prob.components and extra["candidate_sets"] == fit_from_features(
        path, mcfg(), progress=False)[1]["candidate_sets"]
    _, _, _, dropout = read_training_views(path, 1)
    scores = np.asarray(dropout.column("scores").to_pylist(), float)
    objs = np.asarray(dropout.column("object").to_pylist())
    ang = dropout.column("angle_deg").to_numpy()
    c = 0
    cls = models.classes[c]
    a0 = sorted(set(ang[objs == cls]))[0]
    rows = (objs == cls) & (ang == a0)
    want = SS.to_space(scores[rows], space, 1e-5).mean(axis=0)[models.components]
    assert np.allclose(models.Y[c][:, 0], want, rtol=0, atol=1e-12)


def _case(space, seed=3, C=3, F=2, K=4, Nx=2, S=3):
    """Models fitted (hyperparameters drawn) on probability scores mapped to ``space``, and the
    track's dropout probabilities mapped the same way (the cells' one place: ``score_space.to_space``)."""
    rng = np.random.default_rng(seed)
    D = F + 2                                  # whole vectors: clr reads every output
    X, Y = [], []
    for c in range(C):
        th = np.sort(rng.uniform(0, 2 * np.pi, 12 + c))
        logits = np.stack([1.5 * np.sin((d + 1) * th + c) for d in range(D)], axis=1)
        p = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
        X.append(np.c_[np.cos(th), np.sin(th)])
        Y.append(SS.to_space(p, space)[:, :F].T)
    scale = float(np.var(np.concatenate([y.ravel() for y in Y])))
    models = GPClassModels([f"k{c}" for c in range(C)], list(range(F)), X, Y,
                           np.array([[y.mean() for y in Yc] for Yc in Y]), scale * rng.uniform(0.3, 1.0, (C, F)),
                           rng.uniform(0.5, 1.5, (C, F)), scale * rng.uniform(0.02, 0.1, (C, F)),
                           meta={"score_space": SS.record(space, SS.DEFAULT_FLOOR)})
    est = rng.uniform(-1.5, 1.5, (K, 2))
    samples = est[None] + 0.2 * rng.standard_normal((Nx, K, 2))
    samples /= np.linalg.norm(samples, axis=-1, keepdims=True)
    raw = rng.dirichlet(np.ones(D) * 2.0, size=(K, S))
    dropout = SS.for_models(models, raw)[:, :, :F]
    return models, samples, est / np.linalg.norm(est, axis=-1, keepdims=True), dropout


def _literal(models):
    return (models.X, models.Y, models.mean, models.amplitude, models.length_scale, models.noise)


@pytest.mark.parametrize("space", SS.SPACES)
def test_engine_equals_the_literal_oracles_in_every_space(space):
    models, samples, est, dropout = _case(space)
    wu = fuse_with_uncertainty(models, samples, dropout, progress=False)
    assert np.allclose(wu, literal_uncertainty(*_literal(models), samples, dropout), rtol=0, atol=TOL)
    meas = dropout.mean(axis=1)
    mb = fuse_model_based(models, est, meas, progress=False)
    assert np.allclose(mb, literal_model_based(*_literal(models), est, meas), rtol=0, atol=TOL)
    vi = np.exp(ViewIndependent().fuse(TrackInput(dropout=dropout, gp=models)))
    assert np.allclose(vi, literal_view_independent(models.Y, dropout), rtol=0, atol=TOL)


def test_variance_bounds_follow_the_space_width():
    """The bounds and priors of models are stated for a range-1 score; each space maps them by its
    width squared, and the probability space (the paper's, the synthetic default) keeps them as given."""
    b = (1e-6, 1.0)
    assert SS.variance_bounds(b, "probability", 1e-6) == b
    lg = -math.log(1e-6)
    assert SS.variance_bounds(b, "log", 1e-6) == pytest.approx((1e-6 * lg ** 2, lg ** 2), rel=1e-12)
    assert SS.variance_bounds(b, "clr", 1e-6) == SS.variance_bounds(b, "log", 1e-6)
    assert SS.width("logit", 1e-6) == pytest.approx(2 * math.log((1 - 1e-6) / 1e-6), rel=1e-12)
    # the width is the range the transform really spans (the test of the definition, not of the formula)
    p = np.array([0.0, 0.5, 1.0])
    for space in ("log", "logit"):
        y = SS.to_space(p, space, 1e-6)
        assert SS.width(space, 1e-6) == pytest.approx(y.max() - y.min(), rel=1e-9)


def test_a_bursty_log_space_fit_is_not_pinned_at_a_bound():
    """A component that jumps between 1e-5 and 1e-2 over the views (a real softmax's far output) has
    a log-score noise variance of log(1e3)^2 / 4 = 11.9: under the probability space's noise bound 1.0
    the fit cannot reach it (it pins the noise, or here threads a curve through the bursts with a
    length scale under the views' spacing); the bounds mapped into log units leave every
    hyperparameter inside and recover the noise."""
    rng = np.random.default_rng(0)
    th = np.radians(np.arange(0, 360, 10))
    X = np.stack([np.cos(th), np.sin(th)], axis=1)
    p = np.where(rng.random(th.size) < 0.5, 1e-5, 1e-2) * np.exp(0.5 * np.cos(th))
    y = SS.to_space(p, "log", 1e-6)[None, :]

    def fit(bound_space):
        a, n, pr = (SS.variance_bounds(b, bound_space, 1e-6) for b in ((1e-6, 1e2), (1e-6, 1.0), (1e-5, 0.1)))
        return fit_class_models([X], [y], ["c"], [0], restarts=0, amplitude_bounds=a, noise_bounds=n,
                                noise_prior=pr, progress=False)[1][0]

    burst = math.log(1e3) ** 2 / 4
    squeezed = fit("probability")
    assert squeezed["noise"] <= 1.0 < burst / 2
    inside = fit("log")
    assert inside["at_bound"] == [] and burst / 2 < inside["noise"] < 2 * burst
    assert inside["length_scale"] > squeezed["length_scale"]


def test_models_stage_fits_within_the_mapped_bounds(tmp_path):
    path = tmp_path / "bigbird.parquet"
    write_features(path)
    cfg = mcfg(score_space="log", score_floor=1e-5, noise_bounds=(1e-6, 1.0), noise_prior=(1e-5, 0.1))
    _, extra = fit_from_features(path, cfg, progress=False)
    k = SS.variance_scale("log", 1e-5)
    assert extra["fit"]["variance_scale"] == k
    assert extra["fit"]["noise_bounds"] == pytest.approx([1e-6 * k, k], rel=1e-12)
    assert extra["fit"]["noise_prior"] == pytest.approx([1e-5 * k, 0.1 * k], rel=1e-12)
    assert max(d["noise"] for d in extra["diagnostics"]) <= k
    _, prob = fit_from_features(path, mcfg(), progress=False)
    assert prob["fit"]["variance_scale"] == 1.0 and prob["fit"]["noise_bounds"] == list(mcfg().noise_bounds)
