"""Config problems are refused at load with exit 2 (``status`` included), naming where they came
from: the config file, or ``--set`` on the command line; a weights file that is a device or a FIFO
is named as what it is."""
from __future__ import annotations

import json
import os

import pytest

from stages.commands.cli import main
from tests.conftest import ROOT

SYN = str(ROOT / "configs" / "synthetic.toml")


def _run(capsys, *argv) -> tuple[int, str]:
    rc = main(list(argv))
    return rc, capsys.readouterr().err


def _file(tmp_path, body: str) -> str:
    p = tmp_path / "c.toml"
    p.write_text(f'extends = "{SYN}"\n[run]\nartifacts = "{tmp_path / "a"}"\n{body}')
    return str(p)


@pytest.mark.parametrize("metrics", ['["correct_final", "correct_final"]',
                                     '["correct_final", "confident_error_final", "correct_final"]'])
def test_duplicate_primary_metrics_are_refused_from_the_file(tmp_path, capsys, metrics):
    cfg = _file(tmp_path, f"[evaluate]\nprimary_metrics = {metrics}\n")
    rc, err = _run(capsys, "status", "--config", cfg)
    assert rc == 2 and "more than once" in err and "'correct_final'" in err and cfg in err


def test_duplicate_primary_metrics_from_set_name_the_command_line(tmp_path, capsys):
    rc, err = _run(capsys, "status", "--config", SYN, "--set", f"run.artifacts={tmp_path}",
                   "--set", 'evaluate.primary_metrics=["correct_final","correct_final"]')
    assert rc == 2 and "--set on the command line" in err and "more than once" in err


@pytest.mark.parametrize("where", ["file", "set"])
def test_unknown_metric_is_refused_by_status(tmp_path, capsys, where):
    if where == "file":
        cfg = _file(tmp_path, '[evaluate]\nprimary_metrics = ["correct_finale"]\n')
        rc, err = _run(capsys, "status", "--config", cfg)
        assert cfg in err
    else:
        rc, err = _run(capsys, "status", "--config", SYN, "--set", f"run.artifacts={tmp_path}",
                       "--set", 'evaluate.primary_metrics=["nope"]')
        assert "--set on the command line" in err
    assert rc == 2 and "unknown metric" in err


@pytest.mark.parametrize("setting,words", [("evaluate.bootstrap=-5", "below the minimum"),
                                           ("evaluate.n_candidates=13", "exceeds the 12 modelled classes"),
                                           ("data.scans=[\"../x\"]", "plain folder name")])
def test_set_errors_say_they_came_from_the_command_line(tmp_path, capsys, setting, words):
    rc, err = _run(capsys, "status", "--config", SYN, "--set", f"run.artifacts={tmp_path}", "--set", setting)
    assert rc == 2 and words in err
    assert "--set on the command line (over" in err


def test_a_bad_file_is_still_blamed_on_the_file_with_set_given(tmp_path, capsys):
    cfg = _file(tmp_path, "[evaluate]\nbootstrap = -5\n")
    rc, err = _run(capsys, "status", "--config", cfg, "--set", "evaluate.targets=\"all\"")
    assert rc == 2 and err.count(cfg) >= 1 and "--set on the command line" not in err


@pytest.mark.parametrize("n", [3, 7])
def test_n_candidates_above_the_real_imagery_objects_is_a_config_error(tmp_path, capsys, n):
    rc, err = _run(capsys, "status", "--config", str(ROOT / "configs" / "real.toml"),
                   "--set", f"run.artifacts={tmp_path}", "--set", "data.real_imagery.objects=[2,3]",
                   "--set", f"evaluate.n_candidates={n}")
    assert rc == 2 and f"'evaluate.n_candidates' = {n} exceeds the 2 modelled classes" in err


def test_n_candidates_above_the_pool_at_run_time_is_a_config_error():
    from pipeline.evaluation.grid.candidates import candidate_sets
    from pipeline.infra.config import ConfigError

    with pytest.raises(ConfigError, match="'evaluate.n_candidates' = 5 but only 3 classes"):
        candidate_sets(["a", "b", "c"], ["a"], 5, "sampled", 0)


@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "folder", "dangling"])
def test_weights_file_is_named_as_what_it_is(tmp_path, kind):
    from pipeline.scoring.weight_files import WeightsError, WeightsNotFoundError, load_state_dict_file

    p = tmp_path / "w.npz"
    if kind == "fifo":
        os.mkfifo(p)
        with pytest.raises(WeightsError, match="is a FIFO"):
            load_state_dict_file(p)
    elif kind == "dev_zero":
        p.symlink_to("/dev/zero")
        with pytest.raises(WeightsError, match=r"weights file is a character device \(symlink to /dev/zero\)"):
            load_state_dict_file(p)
    elif kind == "folder":
        p.mkdir()
        with pytest.raises(WeightsError, match="is a folder"):
            load_state_dict_file(p)
    else:
        p.symlink_to(tmp_path / "gone.npz")
        with pytest.raises(WeightsNotFoundError, match="weights file is missing .dangling symlink"):
            load_state_dict_file(p)


def test_the_classifier_key_does_not_open_a_fifo(tmp_config, tmp_path):
    from stages.classifier import extra_key

    p = tmp_path / "w.npz"
    os.mkfifo(p)
    cfg = tmp_config({"classifier": {"weights": "path", "path": str(p)}})
    assert extra_key(cfg) == "w.npz|not a regular file"


@pytest.mark.parametrize("names", ['["aunt_jemima_original_syrup", "not_an_avd_object"]',
                                   '["background", "red_bull"]', '["red_bull", "Red_Bull"]'])
def test_a_synthetic_instance_missing_from_the_avd_map_is_a_config_error(tmp_path, capsys, names):
    # before: the data stage found it (exit 1) after its checks; now the config names the key
    rc, err = _run(capsys, "data", "--config", SYN, "--set", f"run.artifacts={tmp_path}",
                   "--set", f"data.synthetic.instances={names}")
    bad = [n for n in json.loads(names) if n not in ("aunt_jemima_original_syrup", "red_bull")][0]
    assert rc == 2 and "'data.synthetic.instances'" in err and repr(bad) in err and "instance map" in err
    assert "--set on the command line (over" in err and not (tmp_path / "synthetic").exists()


def test_the_shipped_instances_and_the_written_map_agree_with_the_config():
    from loaders.synthetic.objects import AVD_INSTANCE_MAP_TEXT
    from pipeline.infra.config import DEFAULT_INSTANCES
    from pipeline.infra.config.inputs import AVD_INSTANCES

    assert AVD_INSTANCE_MAP_TEXT == (ROOT / "docs" / "formats" / "avd_instance_id_map.txt").read_text()
    assert set(DEFAULT_INSTANCES) <= set(AVD_INSTANCES) - {"background"}


@pytest.mark.parametrize("arch", ["resnet_9000", "torchvision:not_a_model", "9lives"])
def test_a_bad_classifier_arch_from_set_names_the_command_line(tmp_path, capsys, arch):
    rc, err = _run(capsys, "status", "--config", SYN, "--set", f"run.artifacts={tmp_path}",
                   "--set", f"classifier.arch={arch}")
    assert rc == 2 and "'classifier.arch'" in err and "--set on the command line (over" in err, err


def test_a_bad_classifier_arch_in_the_file_names_the_file(tmp_path, capsys):
    cfg = _file(tmp_path, '[classifier]\narch = "resnet_9000"\n')
    rc, err = _run(capsys, "status", "--config", cfg, "--set", "classifier.seed=1")
    assert rc == 2 and "'classifier.arch'" in err and cfg in err and "--set on the command line" not in err


@pytest.mark.parametrize("where", ["file", "set"])
@pytest.mark.parametrize("experiments", ['["biased", "biased"]', '["gp_models", "randomized", "sensitivity", "randomized"]'])
def test_duplicate_experiments_are_refused_at_load(tmp_path, capsys, where, experiments):
    if where == "file":
        cfg = _file(tmp_path, f"[evaluate]\nexperiments = {experiments}\n")
        rc, err = _run(capsys, "status", "--config", cfg)
        assert cfg in err
    else:
        rc, err = _run(capsys, "status", "--config", SYN, "--set", f"run.artifacts={tmp_path}",
                       "--set", f"evaluate.experiments={experiments}")
        assert "--set on the command line (over" in err
    assert rc == 2 and "'evaluate.experiments' lists" in err and "more than once" in err
