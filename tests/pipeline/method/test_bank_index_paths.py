"""Paths a model bank's index.json names (ablation bank folders, class files) stay inside the bank
folder: an absolute or ``../..`` entry is refused with the index named, before anything is loaded."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from pipeline.banks.model_bank import ablation_dir
from pipeline.method.gp import ModelFileError
from pipeline.method.gp_files import load_bank, read_bank_index, save_bank
from pipeline.evaluation.grid.banks import load_banks
from tests.pipeline.method.test_gp import make_models

ABL = "models.component_rule=top_mean"


@pytest.fixture
def run(tmp_path):
    """run/models with one ablation bank, and a valid bank outside the run folder."""
    rng = np.random.default_rng(0)
    models = tmp_path / "run" / "models"
    save_bank(make_models(rng), models / ablation_dir(ABL))
    save_bank(make_models(rng), models, extra={"ablations": {ABL: ablation_dir(ABL)}})
    save_bank(make_models(rng), tmp_path / "elsewhere")
    return models


def _set_ablation(models, value):
    ipath = models / "index.json"
    index = json.loads(ipath.read_text())
    index["ablations"][ABL] = value
    ipath.write_text(json.dumps(index))


def test_a_bank_with_its_ablation_inside_loads(run):
    banks, indexes = load_banks(run, (ABL,))
    assert len(banks) == 2 and ABL in banks
    assert indexes[ABL]["classes"] == banks[ABL].classes


@pytest.mark.parametrize("entry, problem", [
    ("ELSEWHERE", "is an absolute path"),
    ("../../elsewhere", "outside"),
    ("..", "outside"),
    (7, "must be a relative path"),
])
def test_an_ablation_entry_leaving_the_models_folder_is_refused(run, entry, problem):
    _set_ablation(run, str(run.parent.parent / "elsewhere") if entry == "ELSEWHERE" else entry)
    with pytest.raises(ModelFileError, match=rf"models/index.json: 'ablations' entry '{ABL}'.*{problem}"):
        load_banks(run, (ABL,))
    with pytest.raises(ModelFileError, match=problem):
        read_bank_index(run)   # every reader of the index, not only evaluate


def test_an_ablation_folder_that_is_a_symlink_out_of_the_folder_is_refused(run):
    link = run / "ablations" / "out"
    os.symlink(run.parent.parent / "elsewhere", link)
    _set_ablation(run, "ablations/out")
    with pytest.raises(ModelFileError, match=r"resolves to .*elsewhere, outside"):
        load_banks(run, (ABL,))


def test_a_class_file_symlinked_out_of_the_folder_is_refused(run):
    index = json.loads((run / "index.json").read_text())
    fname = index["files"][index["classes"][0]]
    (run / fname).unlink()
    os.symlink(run.parent.parent / "elsewhere" / fname, run / fname)
    with pytest.raises(ModelFileError, match=r"the file of class 'class_0'.*outside"):
        load_bank(run)


def test_a_linked_models_folder_still_loads(run, tmp_path):
    # docs/usage.md (configs): a run may link another run's models/ (paper_grade reuses the default's)
    os.symlink(run, tmp_path / "linked")
    banks, _ = load_banks(tmp_path / "linked", (ABL,))
    assert len(banks) == 2


def test_a_dirichlet_parameter_file_linked_out_of_its_folder_is_refused(tmp_path):
    from pipeline.method.dirichlet import DirichletFileError, DirichletModels

    m = DirichletModels(["a", "b"], np.arange(1, 7, dtype=float).reshape(2, 3), floor=1e-5)
    m.save(tmp_path / "elsewhere")
    m.save(tmp_path / "bank")
    assert DirichletModels.load(tmp_path / "bank").classes == ["a", "b"]
    (tmp_path / "bank" / "theta.npz").unlink()
    os.symlink(tmp_path / "elsewhere" / "theta.npz", tmp_path / "bank" / "theta.npz")
    with pytest.raises(DirichletFileError, match=r"index.json: the parameter file 'theta.npz' resolves to .*outside"):
        DirichletModels.load(tmp_path / "bank")
