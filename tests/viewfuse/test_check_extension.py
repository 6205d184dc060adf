"""``vf.check_extension``: each mistake a new user made in each kind (docs/extending.md) is one named
breach (kind, key, hook, cause), every breach of one object is reported at once, the examples of
docs/extending.md pass, and registration refuses what the check finds."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import viewfuse as vf

DOC = Path(__file__).resolve().parents[2] / "docs" / "extending.md"


def breaches(obj, **kw) -> str:
    with pytest.raises(vf.ExtensionError) as e:
        vf.check_extension(obj, **kw)
    return str(e.value)


class Net(vf.Classifier):
    key = "planted_net"
    architecture = "planted"

    def build(self, num_classes, dropout, drop_connect=0.0):
        from torch import nn

        net = nn.Module()        # torchvision's layout: features -> avgpool -> flatten | classifier
        net.features, net.avgpool = nn.Conv2d(3, 2, 8, stride=8), nn.AdaptiveAvgPool2d(1)
        net.classifier = nn.Sequential(nn.Dropout(dropout), nn.Linear(2, num_classes))
        return net

    def last_linear_key(self):
        return "classifier.1.weight"


def test_a_classifier_without_last_linear_key_and_a_bad_colour_are_both_named():
    cls = type("NoKey", (vf.Classifier,), {"key": "planted_net", "color": "no-such-colour",
                                           "build": Net.build})
    text = breaches(cls)
    assert "2 breach(es)" in text
    assert "classifier 'planted_net' (register): " in text
    assert "last_linear_key() is required" in text and "not a colour matplotlib can draw" in text


def test_a_classifier_build_with_a_wrong_signature_is_named():
    cls = type("OneArg", (Net,), {"build": lambda self, num_classes: None})
    text = breaches(cls)
    assert re.search(r"build\(self, num_classes\) cannot be called as build\(num_classes, dropout, drop_connect\)",
                     text), text
    with pytest.raises(vf.ExtensionError, match="classifier 'planted_net' \\(register\\)"):
        vf.register(cls)                                   # registration refuses the same


def test_a_classifier_whose_last_linear_key_names_no_weight_is_named_when_run():
    cls = type("WrongKey", (Net,), {"last_linear_key": lambda self: "classifier.9.weight"})
    assert "(last_linear_key): 'classifier.9.weight' is not a weight with 3 rows" in breaches(cls)


def test_a_correct_classifier_passes_and_scores():
    notes = vf.check_extension(Net)
    assert any("scored two images with MC dropout" in n for n in notes)


def _photos(angle):
    rgb = np.zeros((8, 8, 3), np.uint8)
    return {"mug": {angle: (rgb, np.ones((8, 8), bool))}, "bowl": {0: (rgb, np.ones((8, 8), bool))}}


def test_a_dataset_read_with_angles_as_text_is_named():
    cls = type("Text", (vf.TurntableSource,), {"key": "planted_photos", "read": lambda self, cfg, skips: _photos("90")})
    assert "dataset source 'planted_photos' (read): object 'mug': angle '90' is str, not a whole number" \
        in breaches(cls)
    good = type("Good", (vf.TurntableSource,), {"key": "planted_photos",
                                                "read": lambda self, cfg, skips: _photos(90)})
    assert vf.check_extension(good) == ["read gave 2 objects (0 skipped)"]


def test_a_dataset_without_read_is_named():
    assert "(register): read(cfg, skips) is not implemented" in breaches(type("NoRead", (vf.TurntableSource,),
                                                                              {"key": "planted_photos"}))


def _metric(reduce, column="p_truth", **kw):
    return vf.Metric("planted", "planted", True, column, "final", reduce, key="planted_metric", **kw)


def test_a_metric_whose_reduce_takes_one_argument_is_named():
    text = breaches(_metric(lambda x: x.mean(axis=-1)))
    assert "metric 'planted_metric' (register): reduce" in text and "params" in text


def test_a_metric_column_typo_names_the_column_only():
    text = breaches(_metric(lambda x, params: x.mean(axis=-1), column="p_turth"))
    assert "column(s) ['p_turth']" in text and "steps" not in text


def test_a_metric_that_reduces_the_wrong_axis_is_named_when_run():
    assert "(reduce): values (5, 6) gave" in breaches(_metric(lambda x, params: x.mean()))


def test_a_planner_without_rng_and_one_that_chooses_no_candidate_are_named():
    no_rng = type("NoRng", (vf.Planner,), {"key": "planted_planner", "choose": lambda self, belief, candidates: "v1"})
    assert re.search(r"planner 'planted_planner' \(register\): choose\(self, belief, candidates\) cannot be called "
                     r"as choose\(belief, candidates, rng\)", breaches(no_rng))
    elsewhere = type("Elsewhere", (vf.Planner,), {"key": "planted_planner",
                                                  "choose": lambda self, belief, candidates, rng: "nowhere"})
    assert "planner 'planted_planner' (choose): returned 'nowhere', not one of the candidate nodes" \
        in breaches(elsewhere)


class Toy(vf.FusionMethod):
    key = "planted_method"
    label = short = "planted"
    needs = frozenset({"scores"})
    uses_poses = False

    def fuse(self, t):
        return np.log(np.full(t.own.shape[::2], 1 / t.own.shape[-1]))


def test_method_mistakes_are_named():
    assert "unknown needs ['score']" in breaches(type("Typo", (Toy,), {"needs": frozenset({"score"})}))
    assert "fuse(self) cannot be called as fuse(t)" in breaches(type("Sig", (Toy,), {"fuse": lambda self: None}))
    assert "fusion method 'planted_method' (fuse): its output has shape (3,)" in \
        breaches(type("Shape", (Toy,), {"fuse": lambda self, t: np.zeros(3)}))
    assert vf.check_extension(Toy) == ["fuse ran on 3 views of 3 candidates"]


def test_the_examples_of_docs_extending_pass(monkeypatch):
    """Each python block of docs/extending.md, run with registration left out (nothing stays
    registered), defines objects that pass the check."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(blocks) >= 5, "docs/extending.md lost its examples"
    monkeypatch.setattr(vf, "register", lambda obj: obj)
    checked = []
    for block in blocks:
        ns: dict = {}
        exec(compile(block, str(DOC), "exec"), ns)
        for obj in ns.values():
            if isinstance(obj, vf.Metric) or (isinstance(obj, type) and obj.__module__ == "builtins" and issubclass(
                    obj, (vf.FusionMethod, vf.Classifier, vf.Planner, vf.DatasetSource))):
                vf.check_extension(obj)
                checked.append(obj)
    kinds = {type(o).__name__ if isinstance(o, vf.Metric) else o.__mro__[1].__name__ for o in checked}
    assert kinds >= {"Metric", "FusionMethod", "Classifier", "Planner", "TurntableSource"}, kinds
