"""The instance term's model provider (pipeline/method/methods/instance_term.py) on its own: it is
behind ``models.instance_term``, loads only a bank on the default bank's plan (else names the
folder), narrows to a cell's candidates at the plan's components (a mismatch is refused), puts
them under a test-domain variance, and is served by a bank with a term passed to ``vf.fuse``."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.infra.config import Config
from pipeline.method.gp_files import save_bank
from pipeline.method.gp_instance import InstanceGPClassModels
from pipeline.method.methods.instance_term import INSTANCE_TERM
from pipeline.method.provider import calibrated, providers
from pipeline.method.registry import model_providers
from tests.pipeline.evaluation.grid.test_experiments import ring_models

PLAN = {"c0": {"classes": ["c0", "c1"], "components": [1]}, "c1": {"classes": ["c1", "c2"], "components": [0, 1]}}


def _instance(models, b=0.01):
    labels = [np.arange(len(x)) % 2 for x in models.X]
    return InstanceGPClassModels.from_plain(models, labels, np.full(models.amplitude.shape, b),
                                            np.full(models.amplitude.shape, 2.0))


def test_enabled_by_its_key_of_models():
    import dataclasses

    from pipeline.infra.config.own import with_own

    on = dataclasses.replace(Config(), models=with_own(Config().models, instance_term=True))
    assert INSTANCE_TERM not in {p.key for p in model_providers(Config())}
    assert INSTANCE_TERM in {p.key for p in model_providers(on)}


def test_load_for_cell_and_calibrated(tmp_path):
    p = providers()[INSTANCE_TERM]
    plain = ring_models(C=3, F=2)
    save_bank(plain, tmp_path, extra={"candidate_sets": PLAN})
    save_bank(_instance(plain), tmp_path / INSTANCE_TERM, extra={"candidate_sets": PLAN})
    bank = p.load(tmp_path / INSTANCE_TERM, Config())
    sub = p.for_cell(bank, "c1", ("c1", "c2"), 4)
    assert sub.classes == ["c1", "c2"] and sub.components == [0, 1] and isinstance(sub, InstanceGPClassModels)
    with pytest.raises(ValueError, match=r"plans \['c0', 'c1'\] for the candidates \['c0', 'c2'\]"):
        p.for_cell(bank, "c0", ("c0", "c2"), 4)
    with pytest.raises(ValueError, match="1 scores per crop, the instance bank models component 1"):
        p.for_cell(bank, "c0", ("c0", "c1"), 1)
    tempered = calibrated({INSTANCE_TERM: sub}, (0.5, 0.25))[INSTANCE_TERM]
    assert np.array_equal(tempered.test_variance, np.tile([0.5, 0.25], (2, 1))) and not np.any(sub.test_variance)
    assert calibrated({INSTANCE_TERM: sub}, None)[INSTANCE_TERM] is sub
    assert p.serves(sub) and not p.serves(plain)


def test_a_bank_on_another_plan_is_refused_naming_the_folder(tmp_path):
    plain = ring_models(C=3, F=2)
    save_bank(plain, tmp_path, extra={"candidate_sets": PLAN})
    other = {**PLAN, "c0": {"classes": ["c0", "c1"], "components": [0]}}
    save_bank(_instance(plain), tmp_path / INSTANCE_TERM, extra={"candidate_sets": other})
    with pytest.raises(ValueError, match=rf"{tmp_path / INSTANCE_TERM}: the instance bank's candidate sets differ "
                                         r"from the default bank's for 1 target\(s\) \(first: c0"):
        providers()[INSTANCE_TERM].load(tmp_path / INSTANCE_TERM, Config())
