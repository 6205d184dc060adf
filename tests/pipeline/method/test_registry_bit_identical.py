"""The registry moved the four methods' dispatch, not their numbers: a population cell fused
through the registry (``population.run_cell``) equals, bit for bit, the same cell fused by direct
calls of the engine functions in the order and with the random streams the dispatch had before
the registry (written out here), for every setting, every method, the Dirichlet's spread and
the track difficulty."""
from __future__ import annotations

import zlib

import numpy as np
import pytest

from pipeline.evaluation.grid import experiments as E
from pipeline.evaluation.grid import population as P
from pipeline.evaluation.metrics import spec as M
from pipeline.method import dirichlet_fusion as DF
from pipeline.method.dirichlet import DirichletModels
from pipeline.method.fusion import fuse_model_based, fuse_with_uncertainty, simple_bayes
from pipeline.method.geometry import sample_localization
from tests.pipeline.evaluation.grid.test_experiments import make_track, ring_models

SETTINGS = (P.Setting("biased", "b", 0.2, (0.3, -0.1), 1, 4),
            P.Setting("randomized", "r0", 0.0, (0.0, 0.0), 3, 2),
            P.Setting("randomized", "r2", 0.2, (0.1, 0.0), 30, 5))    # two draw chunks, one engine call


def _cell(seed: int) -> P.Cell:
    """A generated track with every input the four methods read: dropout scores, each candidate's
    own score, whole probability vectors and the candidates' Dirichlet models."""
    models = ring_models(C=3, F=2)
    base = make_track(models, truth=1, K=5, n_s=4, seed=seed)
    rng = np.random.default_rng(seed + 100)
    own = rng.dirichlet(np.ones(3), size=(base.k, 4))
    probs = rng.dirichlet(np.ones(4), size=(base.k, 4))
    data = E.TrackData(base.images, base.cam_xy, base.obj_xy, base.yaw, base.dropout, own=own, probs=probs)
    dm = DirichletModels(models.classes, rng.uniform(0.5, 4.0, size=(3, 4)), floor=1e-5, n_ss=20)
    return P.Cell("default", f"target{seed}", seed, "s1", tuple(models.classes), tuple(models.components), 1, data,
                  SETTINGS, seed=11 + seed, var_floor=1e-6, models={"dirichlet": dm})


def _fused(models, track: E.TrackData, est, smp, var_floor, dirichlet_log):
    """The four methods on (R, K, 2) estimates and (R, N_x, K, 2) samples, by direct engine calls."""
    r = len(est)
    wu = fuse_with_uncertainty(models, track.inputs(smp), np.broadcast_to(track.dropout, (r,) + track.dropout.shape),
                               var_floor=var_floor, return_log=True, progress=False)
    mb = fuse_model_based(models, track.inputs(est), np.broadcast_to(track.measurement, (r,) + track.measurement.shape),
                          return_log=True, progress=False)
    sb = simple_bayes(track.own.mean(axis=1), return_log=True)
    return {"with_uncertainty": wu, "model_based": mb,
            "simple_bayes": np.broadcast_to(sb, (r,) + sb.shape).copy(),
            "dirichlet": np.broadcast_to(dirichlet_log, (r,) + dirichlet_log.shape).copy()}


def _reference(models, cell: P.Cell) -> dict:
    track = cell.data
    drng = np.random.default_rng([cell.seed, zlib.crc32(cell.target.encode()), cell.track, zlib.crc32(b"dirichlet")])
    dm = cell.models["dirichlet"]
    d_log, d_std = DF.fuse_dirichlet(dm, track.probs, n_ss=dm.n_ss, rng=drng)
    posts = {}
    for s in cell.settings:
        rng = P.cell_rng(cell.seed, cell.target, cell.track, s)
        if s.experiment == "biased":
            est = (track.cam_xy + np.asarray(s.bias, float))[None]
            smp = sample_localization(est, s.sigma, s.n_x, rng)
        else:     # drawn 25 realizations at a time: each chunk's errors, then its samples
            ests, smps = [], []
            for a in range(0, s.realizations, 25):
                n = min(s.realizations, a + 25) - a
                noise = rng.normal(0.0, s.sigma, size=(n, track.k, 2)) if s.sigma > 0 else np.zeros((n, track.k, 2))
                ests.append(track.cam_xy[None] + np.asarray(s.bias, float) + noise)
                smps.append(sample_localization(ests[-1], s.sigma, s.n_x, rng))
            est, smp = np.concatenate(ests), np.concatenate(smps)
        posts[(s.experiment, s.label)] = _fused(models, track, est, smp, cell.var_floor, d_log)
    pos = track.cam_xy[:, None, None, :]
    one = {"with_uncertainty": fuse_with_uncertainty(models, track.inputs(pos), track.dropout[:, None],
                                                     var_floor=cell.var_floor, return_log=True, progress=False)[:, 0],
           "model_based": fuse_model_based(models, track.inputs(track.cam_xy[:, None, :]), track.measurement[:, None, :],
                                           return_log=True, progress=False)[:, 0],
           "simple_bayes": simple_bayes(track.own.mean(axis=1)[:, None, :], return_log=True)[:, 0],
           "dirichlet": DF.single_view(dm, track.probs)}
    diff = {m: float(np.mean(M.correct(p, cell.truth, is_log=True))) for m, p in one.items()} | {"views": track.k}
    return {"posts": posts, "difficulty": diff, "dirichlet_std": d_std}


@pytest.mark.parametrize("seed", [0, 1])
def test_the_registered_methods_equal_the_direct_engine_calls_bit_for_bit(seed):
    cell = _cell(seed)
    models = ring_models(C=3, F=2)
    got = P.run_cell({"default": models}, cell)
    want = _reference(models.subset(cell.classes, cell.components), cell)
    assert set(got["posts"]) == set(want["posts"])
    for key, per in want["posts"].items():
        # the paper's four methods, in registry order; the view-independent baseline (its own oracle
        # test: test_view_independent.py) also runs; the instance methods need an instance bank
        assert [m for m in got["posts"][key] if m in per] == list(per), key
        assert set(got["posts"][key]) - set(per) == {"view_independent"}, key
        for m, p in per.items():
            assert got["posts"][key][m].shape == p.shape and np.array_equal(got["posts"][key][m], p), (key, m)
    assert np.array_equal(got["extras"]["dirichlet"]["std"], want["dirichlet_std"])
    assert {k: v for k, v in got["difficulty"].items() if k != "view_independent"} == want["difficulty"]
    assert set(got["seconds"]) == {"with_uncertainty", "model_based", "simple_bayes", "dirichlet", "view_independent"}
