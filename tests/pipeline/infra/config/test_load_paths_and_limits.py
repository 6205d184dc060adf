"""Config loading: where relative paths inherited through ``extends`` resolve (the project root of
the file that sets them), and the ``extends`` chain and nesting limits (named errors, exit 2)."""
from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.infra.config import ConfigError, load_config
from pipeline.infra.config.load import MAX_EXTENDS, MAX_NESTING
from stages.commands.cli import main

REPO = Path(__file__).resolve().parents[4]
DEFAULT = REPO / "configs" / "synthetic.toml"


def test_the_default_writes_under_the_project_root():
    cfg = load_config(DEFAULT)
    assert cfg.artifacts_dir == REPO / "artifacts"
    assert cfg.run_dir == REPO / "artifacts" / "synthetic"


def test_an_out_of_tree_config_extending_the_default_inherits_its_artifacts_folder(tmp_path):
    mine = tmp_path / "elsewhere" / "mine.toml"
    mine.parent.mkdir()
    mine.write_text(f'extends = "{DEFAULT}"\n[run]\nname = "mine"\n')
    cfg = load_config(mine)
    # run.artifacts is set in configs/synthetic.toml: it means <project>/artifacts, as its comment says
    assert cfg.run_dir == REPO / "artifacts" / "mine"


def test_a_path_an_out_of_tree_config_sets_itself_resolves_against_its_own_folder(tmp_path):
    mine = tmp_path / "mine.toml"
    mine.write_text(f'extends = "{DEFAULT}"\n[run]\nartifacts = "out"\n[data]\navd_root = "scans"\n')
    cfg = load_config(mine)
    assert cfg.artifacts_dir == tmp_path / "out"
    assert cfg.path("data.avd_root") == tmp_path / "scans"
    # bigbird_root is not set anywhere: it resolves against the --config file's root
    assert cfg.path("data.bigbird_root") == tmp_path


def test_a_set_override_counts_as_written_in_the_config_file(tmp_path):
    mine = tmp_path / "mine.toml"
    mine.write_text(f'extends = "{DEFAULT}"\n')
    cfg = load_config(mine, {"run": {"artifacts": "runs"}})
    assert cfg.artifacts_dir == tmp_path / "runs"


def test_a_preset_in_configs_extending_the_default_keeps_the_project_root():
    cfg = load_config(REPO / "configs" / "paper_grade.toml")
    assert cfg.artifacts_dir == REPO / "artifacts"


def _chain(folder: Path, n: int) -> Path:
    """c0.toml extends c1.toml ... extends c{n-1}.toml (n files)."""
    for i in range(n):
        (folder / f"c{i}.toml").write_text(f'extends = "c{i + 1}.toml"\n' if i < n - 1 else '[run]\nname = "x"\n')
    return folder / "c0.toml"


def test_an_extends_chain_within_the_limit_loads(tmp_path):
    assert load_config(_chain(tmp_path, MAX_EXTENDS)).run.name == "x"


def test_a_1200_file_extends_chain_is_a_named_error_with_exit_2(tmp_path, capsys):
    top = _chain(tmp_path, 1200)
    with pytest.raises(ConfigError, match=rf"c0.toml: its 'extends' chain is longer than {MAX_EXTENDS} files"):
        load_config(top)
    assert main(["status", "--config", str(top)]) == 2
    err = capsys.readouterr().err
    assert "config error" in err and "c0.toml" in err and "recursion" not in err


@pytest.mark.parametrize("text", [
    "v = " + "[" * 100_000 + "]" * 100_000 + "\n",                # an inline array
    "[run]\nx = " + "{a = " * 100_000 + "1" + "}" * 100_000 + "\n",  # an inline table
    "a" + ".a" * 100_000 + " = 1\n",                              # dotted keys (quadratic in tomllib)
    "[a" + ".a" * 100_000 + "]\n",                                # a table header
])
def test_a_value_nested_100000_deep_is_a_named_error_with_exit_2(tmp_path, capsys, text):
    deep = tmp_path / "deep.toml"
    deep.write_text(text)
    with pytest.raises(ConfigError, match=rf"deep.toml: (line 1: a key|a value) nests deeper than {MAX_NESTING} levels"):
        load_config(deep)
    assert main(["status", "--config", str(deep)]) == 2
    assert "deep.toml" in capsys.readouterr().err


def test_nesting_in_a_base_file_names_that_file(tmp_path):
    (tmp_path / "base.toml").write_text("a = " + "[" * (MAX_NESTING + 1) + "]" * (MAX_NESTING + 1) + "\n")
    (tmp_path / "top.toml").write_text('extends = "base.toml"\n')
    with pytest.raises(ConfigError, match=r"base.toml: a value nests deeper"):
        load_config(tmp_path / "top.toml")


@pytest.mark.parametrize("name", [".stage-cache", ".hidden", ".", "..", "a/b", "x" * 129])
def test_a_run_name_that_is_not_a_plain_visible_folder_is_refused_with_the_key(name):
    """A leading dot would put the run among the runner's own folders (<artifacts>/.stage-cache)."""
    with pytest.raises(ConfigError, match=r"'run.name' = .* must be a plain folder name"):
        load_config(DEFAULT, {"run": {"name": name}})
    assert load_config(DEFAULT, {"run": {"name": "a.b_c-1"}}).run.name == "a.b_c-1"   # dots inside are fine
