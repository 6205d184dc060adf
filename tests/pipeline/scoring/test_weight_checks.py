"""Weight files checked when loaded (dtype, finite values, an output layer with rows), and feature
tables never built from non-finite scores (the error names the view)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.scoring.features import build_table
from pipeline.scoring.weight_files import WeightsError, load_state_dict_file, num_classes_of, save_state_dict_npz
from tests.pipeline.scoring.test_table_checks import _table


def _npz(tmp_path, **arrays):
    path = tmp_path / "w.npz"
    np.savez(path, **arrays)
    return path


def _good():
    rng = np.random.default_rng(0)
    return {"classifier.6.weight": rng.standard_normal((3, 8)).astype(np.float32),
            "classifier.6.bias": np.zeros(3, np.float32)}


def test_a_good_file_loads_and_gives_its_class_count(tmp_path):
    path = tmp_path / "ok.npz"
    save_state_dict_npz({k: torch.from_numpy(v) for k, v in _good().items()}, path)
    state = load_state_dict_file(path)
    assert num_classes_of(state, path) == 3
    assert torch.equal(state["classifier.6.weight"], torch.from_numpy(_good()["classifier.6.weight"]))


def test_an_output_layer_with_zero_rows_is_named(tmp_path):
    path = _npz(tmp_path, **{"classifier.6.weight": np.zeros((0, 8), np.float32)})
    with pytest.raises(WeightsError, match=r"w.npz: 'classifier.6.weight' is \(0, 8\): no output rows"):
        num_classes_of(load_state_dict_file(path), path)


def test_a_string_array_is_a_weights_error_not_a_type_error(tmp_path):
    path = _npz(tmp_path, **{**_good(), "classifier.6.bias": np.array(["a", "b", "c"])})
    with pytest.raises(WeightsError, match=r"w.npz: entry 'classifier.6.bias' holds <U1 values, expected numbers"):
        load_state_dict_file(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_weights_are_refused(tmp_path, bad):
    w = _good()
    w["classifier.6.weight"][1, 2] = bad
    path = _npz(tmp_path, **w)
    with pytest.raises(WeightsError, match=r"entry 'classifier.6.weight' \(3, 8\) has 1 non-finite value"):
        load_state_dict_file(path)


def test_non_finite_weights_in_a_torch_file_are_refused(tmp_path):
    path = tmp_path / "w.pth"
    torch.save({k: torch.full_like(torch.from_numpy(v), float("nan")) for k, v in _good().items()}, path)
    with pytest.raises(WeightsError, match=r"w.pth: entry 'classifier.6.(weight|bias)'.*non-finite"):
        load_state_dict_file(path)


@pytest.mark.parametrize("where", ["det", "mc"])
def test_a_feature_table_is_never_built_from_non_finite_scores(where):
    t = _table("avd")
    cols = {n: t.column(n).to_pylist()[::3] for n in t.column_names if n not in ("scores", "pass")}
    n = len(cols["scan"])
    det = np.full((n, 3), 1 / 3)
    mc = np.full((n, 2, 3), 1 / 3)
    (det if where == "det" else mc)[2, ..., 0] = np.nan
    with pytest.raises(ValueError, match=r"avd features: non-finite scores for 1 of 4 crop\(s\), the first at "
                                         r"scan 'scan_0', image 'image_0', instance 'instance_0'"):
        build_table("avd", cols, det, mc)
    det[:], mc[:] = 1 / 3, 1 / 3
    assert build_table("avd", cols, det, mc).num_rows == n * 3
