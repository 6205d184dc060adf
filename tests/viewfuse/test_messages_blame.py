"""Messages blame the party at fault: the caller's argument (vf.fuse, vf.fit_models,
vf.evaluate_population), the file (--config), the signal (a killed worker); never an internal
function's name or a method's output for what the caller passed in. Each case with a variant."""
from __future__ import annotations

import os
import signal
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import pandas as pd
import pytest

import viewfuse as vf
from pipeline.infra.config.fields import ConfigError
from pipeline.infra.config.load import load_config
from pipeline.infra.workers import worker_pool

TH = np.linspace(0, 2 * np.pi, 12, endpoint=False)


@pytest.fixture(scope="module")
def models():
    return vf.fit_models({"a": (TH, np.c_[0.5 + 0.3 * np.cos(TH), 0.5 - 0.3 * np.cos(TH)]),
                          "b": (TH, np.c_[0.5 + 0.3 * np.sin(TH), 0.5 - 0.3 * np.sin(TH)])}, restarts=0)


def _fuse(models, key, **kw):
    args = dict(cameras=2 * np.c_[np.cos(TH[:4]), np.sin(TH[:4])], dropout=np.full((4, 5, 2), 0.5), sigma=0.1, n_x=5)
    args.update(kw)
    return vf.fuse(key, models, **args)


@pytest.mark.parametrize("key", ["model_based", "with_uncertainty"])
@pytest.mark.parametrize("arg,value", [("dropout", np.full((4, 5, 2), 1e308)),          # overflowed as the method's NaN
                                       ("cameras", 1e300 * np.ones((4, 2))),              # variant: positions
                                       ("dropout", np.where(np.eye(4, 2)[:, None, :] > 0, np.nan, 0.5))])
def test_a_callers_extreme_or_non_finite_input_is_the_callers_argument(models, key, arg, value):
    with pytest.raises(ValueError, match=rf"^fuse: {arg} (holds .* too large for the fusion's arithmetic|must be finite)") as e:
        _fuse(models, key, **{arg: value})
    assert key not in str(e.value) and "output" not in str(e.value)


def test_scores_within_the_bound_still_fuse(models):
    assert np.isfinite(_fuse(models, "model_based", dropout=np.full((4, 5, 2), 1e100))).all()


@pytest.mark.parametrize("angles,kw,cause", [
    (np.zeros(4), {}, r"all 4 views are from one direction"),
    (np.array([0.0]), {}, r"1 view; a class needs at least 2"),
    (np.array([0.0, np.pi, 0.0, np.pi]), {}, r"every pair of the 2 directions is 2 apart.*hyperprior='none'"),
    (np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3]), {}, r"every pair of the 3 directions"),   # variant
])
def test_fit_models_names_the_argument_not_an_internal_function(angles, kw, cause):
    scores = np.random.default_rng(0).random((len(angles), 2))
    with pytest.raises(ValueError, match=r"^fit_models: samples\['a'\] angles: " + cause) as e:
        vf.fit_models({"a": (angles, scores), "b": (TH, np.random.default_rng(1).random((12, 2)))}, restarts=0, **kw)
    assert "input_range" not in str(e.value) and "inverse_gamma_for" not in str(e.value)


def test_three_equidistant_directions_fit_without_the_length_scale_prior():
    ang = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
    vf.fit_models({"a": (ang, np.random.default_rng(0).random((3, 2)))}, restarts=0, hyperprior="none")


def _die(_):
    os.kill(os.getpid(), signal.SIGKILL)


def _exit(_):
    os._exit(3)


@pytest.mark.parametrize("job,said", [(_die, r"was killed by SIGKILL \(kill -9, or the kernel's out-of-memory killer\)"),
                                      (_exit, r"exited with status 3")])               # variant: an exit
def test_a_dead_worker_is_named_by_its_signal_or_status(job, said):
    with pytest.raises(BrokenProcessPool, match=r"worker process \d+ " + said):
        with worker_pool(1, start_method="fork") as pool:
            pool.submit(job, 0).result()


def test_the_cli_does_not_blame_the_launcher_for_a_killed_worker(monkeypatch, capsys):
    from stages.commands import cli

    def boom(args):
        raise BrokenProcessPool("worker process 12 was killed by SIGKILL (kill -9, or the kernel's out-of-memory killer)")
    monkeypatch.setattr(cli, "_main", boom)
    assert cli.main(["status"]) == 1
    err = capsys.readouterr().err
    assert "killed by SIGKILL" in err and "__main__" not in err and "message is above" not in err


@pytest.mark.parametrize("path,said", [("/dev/zero", "is a character device, not a regular file"),
                                       ("{tmp}", "is a folder, not a regular file")])      # variant: a folder
def test_a_config_that_is_not_a_regular_file_says_what_it_is(tmp_path, path, said):
    with pytest.raises(ConfigError, match=said) as e:
        load_config(path.format(tmp=tmp_path))
    assert "not found" not in str(e.value)


def test_a_config_too_large_is_refused_unparsed(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text("#" * (2 << 20))
    with pytest.raises(ConfigError, match=r"big.toml: more than \d+ bytes, too large for a config file"):
        load_config(big)


def _table(track):
    rows = [dict(target=f"t{t}", track=track(k), method=m, correct_final=float((t + k) % 2))
            for t in range(3) for k in range(2) for m in ("with_uncertainty", "model_based")]
    return pd.DataFrame(rows)


@pytest.mark.parametrize("track", [lambda k: f"tr{k}", lambda k: k + 0.5])            # text, and a variant: fractions
def test_evaluate_population_names_the_track_column(track):
    with pytest.raises(ValueError, match=r"^evaluate_population: results' 'track' column must hold integer track "
                                         r"numbers .* number text labels first"):
        vf.evaluate_population(_table(track), metrics=["correct_final"], n_boot=20)


def test_evaluate_population_takes_integer_tracks_as_floats_too():
    out = vf.evaluate_population(_table(lambda k: float(k)), metrics=["correct_final"], n_boot=20)
    assert out
