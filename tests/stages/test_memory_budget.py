"""Settings whose memory grows are refused or bounded before the work starts: every
check here runs under a tiny run.memory_gb, so a refusal costs nothing and nothing large is made."""
from __future__ import annotations

import dataclasses

import pytest

from pipeline.infra.config import Config, ConfigError
from stages.commands.cli import main


def test_a_huge_training_set_is_refused_before_rendering(tmp_path, capsys):
    rc = main(["classifier", "--set", f"run.artifacts={tmp_path}",
               "--set", "classifier.training.train_images=10000000"])
    err = capsys.readouterr().err
    assert rc == 2, err
    line = [ln for ln in err.splitlines() if "config error" in ln][0]
    assert "'classifier.training.train_images' = 10000000" in line and "GiB" in line and "run.memory_gb" in line
    assert not any((tmp_path / "synthetic").glob(".classifier.tmp*"))


def test_the_default_training_set_passes_the_check_that_refuses_the_huge_one():
    from pipeline.infra import footprints
    from pipeline.infra.budget import GIB
    assert footprints.classifier_training(Config().classifier) < 4 * GIB


def sim_cfg(**kw):
    c = Config()
    return dataclasses.replace(c, simulate=dataclasses.replace(c.simulate, **kw))


def test_simulate_chunk_is_bounded_by_memory_and_results_do_not_change():
    from stages.simulate import _fit_budget
    from pipeline.infra.budget import GIB
    sim = _fit_budget(sim_cfg(chunk=100_000, realizations=100).simulate, GIB)
    assert 1 <= sim.chunk < 1000  # a localization_bias realization holds megabytes of GP covariances
    assert _fit_budget(sim_cfg().simulate, GIB).chunk == 25   # the default stays


def test_simulate_results_depend_on_the_chunk_only_by_rounding():
    # every realization draws from its own generator; the batched fusion's sums round differently
    import numpy as np
    from pipeline.evaluation.simulation import scenarios as S
    sim = sim_cfg(realizations=5, n_loc_samples=4, n_samples=3, restarts=0, track_steps=5).simulate
    models = S.configured_models(S.fit_models(sim)[0], sim)
    a = S.run_scenario(models, "localization_bias", dataclasses.replace(sim, chunk=2))
    b = S.run_scenario(models, "localization_bias", dataclasses.replace(sim, chunk=5))
    for m in a.posteriors:
        np.testing.assert_allclose(a.posteriors[m], b.posteriors[m], rtol=1e-12, atol=1e-15)


def test_simulate_refuses_a_results_table_over_the_budget(tmp_path, capsys):
    rc = main(["simulate", "--set", f"run.artifacts={tmp_path}", "--set", "run.memory_gb=0.5",
               "--set", "simulate.chunk=100000", "--set", "simulate.realizations=100000"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "'simulate.realizations' = 100000" in err and "0.50 GiB" in err


def test_evaluate_refuses_a_bootstrap_over_the_budget():
    from stages.evaluate import check_budget
    c = Config()
    tiny = dataclasses.replace(c, run=dataclasses.replace(c.run, memory_gb=0.5))
    check_budget(tiny, 12, 8)  # the defaults fit in half a GiB
    big = dataclasses.replace(tiny, evaluate=dataclasses.replace(c.evaluate, bootstrap=1_000_000))
    with pytest.raises(ConfigError, match=r"'evaluate.bootstrap' = 1000000.*12 targets x up to 8 tracks"):
        check_budget(big, 12, 8)


def test_evaluate_refuses_cells_whose_results_exceed_the_budget():
    from stages.evaluate import check_budget
    c = Config()
    ev = dataclasses.replace(c.evaluate, randomized=dataclasses.replace(c.evaluate.randomized, realizations=500_000,
                                                                         n_loc_samples=1))
    big = dataclasses.replace(c, run=dataclasses.replace(c.run, memory_gb=2), evaluate=ev)
    with pytest.raises(ConfigError, match=r"'evaluate.randomized.realizations' = 500000"):
        check_budget(big, 12, 8)


def test_data_workers_are_capped_by_the_cores(tmp_path, monkeypatch, caplog):
    import contextlib
    import json
    import logging

    import loaders.sources.synthetic
    from pipeline.infra.budget import cores
    from tests.support.tiny_world import TINY
    asked = []

    @contextlib.contextmanager
    def no_pool(n, **kw):  # record the count, render nothing
        asked.append(n)
        raise RuntimeError("stopped by the test")
        yield
    monkeypatch.setattr(loaders.sources.synthetic, "worker_pool", no_pool)
    args = ["data", "--set", f"run.artifacts={tmp_path}", "--set", f"data.scans={json.dumps(TINY['data']['scans'])}",
            "--set", "data.synthetic.instances_per_scan=0", "--set", "data.synthetic.workers=64"]
    with caplog.at_level(logging.WARNING, "viewfuse"):
        assert main(args) == 1
    if cores() == 1:
        assert asked == []  # one worker: rendered in this process, not a pool
    else:
        assert asked == [min(64, cores())]
    assert "data.synthetic.workers = 64 capped" in caplog.text
