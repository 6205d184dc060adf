"""Config values are checked at load, every section (``[simulate]`` included), with the key named:
numeric ranges for every number, the cross-key cases (extreme GP bounds, localization biases that
overflow, a target that is not a modelled instance), strings that reach matplotlib; and the GP-fit
defaults are the config's."""
from __future__ import annotations

import dataclasses
import inspect
import io
import typing

import numpy as np
import pytest

from pipeline.infra.config import Config, ConfigError, ModelsConfig, bounds_problem


@pytest.mark.parametrize("over, key", [
    ({"models": {"length_scale_bounds": [1e-300, 1e300]}}, "'models.length_scale_bounds[0]'"),
    ({"models": {"amplitude_bounds": [1e-6, 1e300]}}, "'models.amplitude_bounds[1]'"),
    ({"evaluate": {"randomized": {"bias_m": [1e300, 0.0]}}}, "'evaluate.randomized.bias_m[0]'"),
    ({"evaluate": {"biased": {"bias_m": [0.0, -1e9]}}}, "'evaluate.biased.bias_m[1]'"),
    ({"simulate": {"length_scale_bounds": [0.0, 30.0]}}, "'simulate.length_scale_bounds[0]'"),
    ({"data": {"seed": 2**70}}, "'data.seed'"),
    ({"data": {"synthetic": {"room_size_m": [1e9, 3.0]}}}, "'data.synthetic.room_size_m[0]'"),
    ({"data": {"max_image_megapixels": 0.0}}, "'data.max_image_megapixels'"),
])
def test_out_of_range_numbers_are_refused_at_load(tmp_config, over, key):
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        tmp_config(over)


def test_every_numeric_key_has_a_range():
    """Every int/float key (and every item of a numeric list) is range-checked at load."""
    missing = []

    def walk(cls, prefix):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if f.metadata.get("internal"):
                continue
            tp = hints[f.name]
            if dataclasses.is_dataclass(tp):
                walk(tp, prefix + f.name + ".")
                continue
            inner = typing.get_args(tp)[0] if typing.get_origin(tp) is tuple else tp
            md = f.metadata
            if inner in (int, float) and not md.get("choices") and (md.get("lo") is None or md.get("hi") is None):
                missing.append(prefix + f.name)
    walk(Config, "")
    assert missing == []


def test_a_target_that_is_not_a_modelled_instance_is_named(tmp_config):
    with pytest.raises(ConfigError, match="'evaluate.targets' names 'nope', which is not a modelled instance"):
        tmp_config({"evaluate": {"targets": ["nope"]}})
    with pytest.raises(ConfigError, match="not a modelled instance"):  # a list of classes that lacks it
        tmp_config({"models": {"classes": ["mahatma_rice", "red_bull"]}, "evaluate": {"targets": ["pepto_bismol"]}})
    tmp_config({"evaluate": {"targets": ["red_bull"]}})


def test_the_models_stage_names_an_unknown_target_when_the_data_decides(tmp_path):
    # Real data with models.classes = 'all': the config cannot know the classes; the stage names it.
    from stages.models import fit_from_features
    from tests.stages.test_models_stage import write_features

    p = tmp_path / "bigbird.parquet"
    write_features(p)
    with pytest.raises(ValueError, match="'evaluate.targets' names 'nope', which is not a modelled instance"):
        fit_from_features(p, ModelsConfig(restarts=0), targets=["nope"], n_candidates=2, progress=False)


def test_more_candidates_than_modelled_classes_is_a_config_error(tmp_config):
    classes = ["mahatma_rice", "red_bull", "pepto_bismol"]
    for mode in ("sampled", "hard"):
        with pytest.raises(ConfigError, match=f"'evaluate.n_candidates' = 4 exceeds the 3 modelled classes.*{mode}"):
            tmp_config({"models": {"classes": classes}, "evaluate": {"n_candidates": 4, "candidates": mode}})
        tmp_config({"models": {"classes": classes}, "evaluate": {"n_candidates": 3, "candidates": mode}})
    tmp_config({"models": {"classes": classes}, "evaluate": {"n_candidates": 4, "candidates": "all"}})  # ignored


def test_the_models_stage_plans_hard_sets_from_the_deterministic_means(tmp_path):
    # The plan the evaluate stage reads (models/index.json's candidate_sets) holds the hard sets
    # computed from each class's mean deterministic-pass score vector over its training views
    # (here they differ from the seeded draw for two of the five targets).
    from pipeline.evaluation.grid.candidates import candidate_sets
    from stages.models import fit_from_features
    from tests.stages.test_models_stage import write_features

    classes = [f"obj_{i}" for i in range(5)]
    p = tmp_path / "bigbird.parquet"
    truth = write_features(p, classes=classes, n_angles=12, shift=0.3)
    means = {c: s.mean(axis=0) for c, (_, s) in truth.items()}
    _, extra = fit_from_features(p, ModelsConfig(classes=tuple(classes), n_components=2, restarts=0, min_views=8),
                                 n_candidates=3, candidates="hard", progress=False)
    expected = candidate_sets(classes, classes, 3, "hard", 0, class_means=means)
    assert {t: v["classes"] for t, v in extra["candidate_sets"].items()} == expected
    assert expected != candidate_sets(classes, classes, 3, "sampled", 0)


def test_the_simulate_section_is_cross_checked_at_load(tmp_config):
    with pytest.raises(ConfigError, match="'simulate.example_realization' = 400 must be below"):
        tmp_config({"simulate": {"example_realization": 400}})
    with pytest.raises(ConfigError, match="'simulate.class_names' must list 3 distinct names"):
        tmp_config({"simulate": {"class_names": ["a", "a", "b"]}})


def test_mathtext_in_a_config_string_is_drawn_literally(tmp_config):
    from reports.shared.figures import new_figure

    cfg = tmp_config({"simulate": {"class_names": ["$\\foo$", "class 2", "$x"]}})
    fig, ax = new_figure()
    ax.plot([0, 1], [0, 1], label=cfg.simulate.class_names[0])
    ax.set_title(cfg.simulate.class_names[0])
    ax.legend()
    fig.savefig(io.BytesIO(), format="png")  # raised matplotlib's ParseFatalException before
    assert ax.get_title() == "$\\foo$"


def test_gp_fit_defaults_are_the_config_defaults():
    from pipeline.method.gp_fit import fit_class_models

    m = ModelsConfig()
    params = inspect.signature(fit_class_models).parameters
    for key in ("amplitude_bounds", "length_scale_bounds", "noise_bounds", "noise_prior", "hyperprior",
                "restarts", "seed"):
        assert params[key].default == getattr(m, key), key


def test_one_bounds_check_for_config_fits_and_simulation(tmp_config):
    from pipeline.method.gp_fit import fit_class_models

    words = bounds_problem((2.0, 1.0))
    assert words and bounds_problem((1e-3, 1.0)) is None and bounds_problem((1.0,))
    with pytest.raises(ConfigError) as e:
        tmp_config({"models": {"noise_bounds": [0.5, 0.1]}})
    assert words.replace("[2.0, 1.0]", "[0.5, 0.1]") in str(e.value)
    with pytest.raises(ConfigError) as e:
        tmp_config({"simulate": {"noise_bounds": [0.5, 0.1]}})
    assert words.replace("[2.0, 1.0]", "[0.5, 0.1]") in str(e.value)
    X, Y = np.zeros((4, 2)), [np.zeros((1, 4))]
    with pytest.raises(ValueError) as e:
        fit_class_models([X], Y, ["a"], [0], noise_bounds=(2.0, 1.0), progress=False)
    assert words in str(e.value)
